"""Reading an XML file with errors that name it (DIMAP and RPC readers)."""
from __future__ import annotations

import xml.etree.ElementTree as ElementTree

from ..errors import BlockError

__all__ = ["xml_root"]


def xml_root(path: str, what: str) -> ElementTree.Element:
    """The root element of ``path``; a file that is not XML or cannot be read raises BlockError."""
    try:
        return ElementTree.parse(path).getroot()
    except ElementTree.ParseError as exc:
        raise BlockError(path, f"not XML: {exc}", exc.position[0] if exc.position else None) from None
    except (LookupError, ValueError) as exc:        # an unknown encoding declared, a broken character reference
        raise BlockError(path, f"not XML: {exc}") from None
    except OSError as exc:
        raise BlockError(path, f"cannot read the {what}: {exc.strerror}") from None
