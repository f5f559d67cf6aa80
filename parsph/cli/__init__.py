"""The command line: ``parsph run|check|scenes|info|plot|study``."""
from parsph.cli.main import main  # noqa: F401  (the console script)
