"""`python -m eval`: the same commands as the `eval` console script (eval.cli)."""

from eval.cli import main

if __name__ == "__main__":
    main()
