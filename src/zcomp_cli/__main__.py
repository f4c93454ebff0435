"""``python -m zcomp_cli``: the zcomp command. A Ctrl-C while zcomp is still loading
exits with 130, quietly, as it does later (no traceback of an interrupted import)."""

import sys

try:
    from zcomp_cli.cli import main
except KeyboardInterrupt:  # pragma: no cover - a race with the user's finger
    sys.exit(130)

if __name__ == "__main__":  # pragma: no cover
    main()
