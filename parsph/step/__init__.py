"""The step and the run: the driver, the stages a scene calls for, checkpoints, faults, probes."""
