"""`python -m campaign.cli`: the same as the `trackcal` command."""

import sys

from campaign.cli import main

sys.exit(main())
