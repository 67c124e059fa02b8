"""``python -m nmrl``: the ``nmrl`` command (nmrl/cli) without the console script on PATH."""

from nmrl.cli import main

if __name__ == "__main__":
    main()
