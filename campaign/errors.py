"""The campaign layer's errors: one base the command line catches (one line on stderr, exit 2).

CampaignError  a file, plan, session, cell or value the campaign cannot use; the message names it
  InputError   an input (table, config, model, plan file, option value) that cannot be used
  UsageError   a command-line mistake (a missing or conflicting option): raised by campaign.cli only
Other subclasses live with their subject: PlanError (engine.steps), StoreError (session.store), ReplayDivergence
(engine.recording), KrlError (krl). A campaign that stops safely is no error: the engine's RunResult says so
(exit status "stopped"), and the command line makes it one line.
"""


class CampaignError(Exception):
    """A campaign-level refusal the user can act on; the message says what and where."""


class InputError(CampaignError):
    """An input that cannot be used: the message names the file, row or key."""


class UsageError(CampaignError):
    """A command-line mistake."""
