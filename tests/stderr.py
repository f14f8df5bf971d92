"""What a command said on stderr besides the stages' progress lines (INFO: what a stage draws and fits)."""

PROGRESS = ("pdeinv train: prior stage: ", "pdeinv train: calibration stage: ",
            "pdeinv train: prior fit step ")


def said(err: str) -> list[str]:
    """The lines of ``err`` that are not progress (warnings, errors, the result)."""
    return [line for line in err.splitlines() if not line.startswith(PROGRESS)]
