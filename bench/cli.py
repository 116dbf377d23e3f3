"""Command-line entry point ``bench``."""

from __future__ import annotations

import argparse
import sys

from bench import __version__


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="bench", description="PMLSM sensorless drive bench")
    parser.add_argument("--version", action="version", version=f"bench {__version__}")
    parser.parse_args(argv)
    print(f"bench {__version__}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
