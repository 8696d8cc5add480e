"""``selfcal import FORMAT``: one module per format, each with ``HELP``, ``add_arguments(parser)`` and
``run(args) -> int``. A new format is one module and one line here."""
from . import bal, colmap, gnss, isis

#: format -> module
IMPORTERS = {
    "colmap": colmap,
    "bal": bal,
    "isis": isis,
    "gnss": gnss,
}
