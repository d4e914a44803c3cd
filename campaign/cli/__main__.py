"""`python -m campaign.cli`: the same as the `trackcal` command."""

import sys

from trackcal.campaign.cli import main

sys.exit(main())
