"""What a command said on stderr besides the stages' progress lines (INFO: the plan, what a stage draws
and fits, the rule stage's progress)."""

import re

PROGRESS = re.compile(r"pdeinv train: (prior stage: |calibration stage: |prior fit step |plan: |"
                      r"step \d+(/\d+)?, loss )")


def said(err: str) -> list[str]:
    """The lines of ``err`` that are not progress (warnings, errors, the result)."""
    return [line for line in err.splitlines() if not PROGRESS.match(line)]
