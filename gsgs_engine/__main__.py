import sys

from gsgs_engine.cli import main

if __name__ == "__main__":
    sys.exit(main())
