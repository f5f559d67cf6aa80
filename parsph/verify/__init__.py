"""Known answers of scenes (analytic solutions, experiments, the paper): the relative
error of a finished run, for ``parsph study`` and the tests."""
