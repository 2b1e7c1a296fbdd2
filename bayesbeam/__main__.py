"""Allow ``python -m bayesbeam``."""

from bayesbeam.cli import main

raise SystemExit(main())
