"""``python -m trivsel.blocks KIND OUT [ITEM ...]``: one job of a blocked run (the workflow's rules)."""

from . import main

raise SystemExit(main())
