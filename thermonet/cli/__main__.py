"""``python -m thermonet.cli``: the command line (:func:`thermonet.cli.run`)."""

from . import run

if __name__ == "__main__":
    run()
