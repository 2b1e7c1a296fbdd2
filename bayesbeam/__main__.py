"""Allow ``python -m bayesbeam``."""

from bayesbeam.cli.main import main

raise SystemExit(main())
