"""`python -m benchgen` runs the `benchgen` command line."""

from benchgen.cli import main

if __name__ == "__main__":
    main(prog_name="benchgen")
