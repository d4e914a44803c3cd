"""The campaign layer's errors: one base the command line catches (one line on stderr, exit 2).

CampaignError  a file, plan, session, cell or value the campaign cannot use; the message names it
  InputError   an input (table, config, model, plan file, option value) that cannot be used
    OptionError  a job's option value that cannot be used: it names the option (a field of the job's options), the
                 command line spells it as its flag (`--params: ...`)
  UsageError   a command-line mistake (a missing or conflicting option): raised by campaign.cli only
Other subclasses live with their subject: PlanError (engine.steps), StoreError (session.store), ReplayDivergence
(engine.recording), NotAnalysedError (jobs.end_of_run). A campaign that stops safely is no
error: the engine's RunResult says so (exit status "stopped"), and the command line makes it one line.
"""


class CampaignError(Exception):
    """A campaign-level refusal the user can act on; the message says what and where."""


class InputError(CampaignError):
    """An input that cannot be used: the message names the file, row or key."""


class UsageError(CampaignError):
    """A command-line mistake."""


class OptionError(InputError):
    """An option value a job cannot use. `template` (str.format) holds {0}, {1} ... where the options go and
    {name} where `values` go; `options` are the names of the job's option fields (test_pose). str() writes the
    field names; `spelled(flag)` lets the command line write its flags (--test-pose) instead."""

    def __init__(self, template: str, *options: str, **values) -> None:
        self.template, self.options, self.values = template, options, values
        super().__init__(self.spelled(str))

    def spelled(self, name) -> str:
        return self.template.format(*(name(o) for o in self.options), **self.values)
