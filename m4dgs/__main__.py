"""`python -m m4dgs` runs the `m4dgs` command line."""

from m4dgs.cli import main

if __name__ == "__main__":
    main(prog_name="m4dgs")
