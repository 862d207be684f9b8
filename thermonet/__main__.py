"""``python -m thermonet``: the command line (:func:`thermonet.cli.run`)."""

from .cli import run

if __name__ == "__main__":
    run()
