"""The CLI's method names, importable without torch (``pdeinv --help``); :data:`.presets.METHODS`
has one factory per name (a test checks they agree)."""

METHOD_NAMES = ("adam", "gd", "hig", "sip", "supervised")
