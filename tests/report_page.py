"""report.html as the report tests read it (one parser for tests/test_report.py and tests/test_report_sections.py)."""
from html.parser import HTMLParser


class Row(list):
    """A table row: its cells as (text, data-summary key or None, data-value or None); ``flag`` when the row's
    class is "flag" (a check point beyond 3 sigma, a rejected observation)."""

    def __init__(self, flag: bool):
        super().__init__()
        self.flag = flag


class ReportPage(HTMLParser):
    """The summary cells (key, exact value, text), the images' src and alt texts, every table with an id (its rows,
    :class:`Row`), and the ids of the tables that lie in a <details> fold."""

    def __init__(self):
        super().__init__()
        self.cells, self.images, self.alts, self.tables, self.folded = [], [], [], {}, set()
        self._table = self._row = self._cell = None
        self._details = 0

    def handle_starttag(self, tag, attrs):
        attrs = dict(attrs)
        if tag == "details":
            self._details += 1
        elif tag == "img":
            self.images.append(attrs.get("src", ""))
            self.alts.append(attrs.get("alt", ""))
        elif tag == "table" and attrs.get("id"):
            self._table = attrs["id"]
            self.tables[self._table] = []
            if self._details:
                self.folded.add(self._table)
        elif tag == "tr" and self._table:
            self._row = Row(attrs.get("class") == "flag")
        elif tag == "td":
            self._cell = ["", attrs.get("data-summary"), attrs.get("data-value")]

    def handle_endtag(self, tag):
        if tag == "details":
            self._details -= 1
        elif tag == "td" and self._cell is not None:
            text, key, value = self._cell
            if key is not None:
                self.cells.append((key, value, text))
            if self._row is not None:
                self._row.append(tuple(self._cell))
            self._cell = None
        elif tag == "tr" and self._row is not None:
            if self._row:
                self.tables[self._table].append(self._row)
            self._row = None
        elif tag == "table":
            self._table = None

    def handle_data(self, data):
        if self._cell is not None:
            self._cell[0] += data


def read_report(path) -> ReportPage:
    page = ReportPage()
    with open(path, encoding="utf-8") as handle:
        page.feed(handle.read())
    return page
