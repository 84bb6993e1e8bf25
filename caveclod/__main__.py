"""``python -m caveclod``: the same command line as the ``caveclod`` script."""

from .cli import main

if __name__ == "__main__":
    raise SystemExit(main())
