"""`python -m vcirun`: the command line, as the `vcirun` script."""
from vcirun.cli.main import app

if __name__ == "__main__":
    app(prog_name="vcirun")
