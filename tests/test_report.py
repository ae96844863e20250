"""The report an engineer sends: one HTML file with every image in it, the answer first, a
caption per figure from the study's own numbers, the provenance last; its figures reused
while the archive and the code that draws them are unchanged."""

import base64
import html
import html.parser
import re

import netCDF4
import pytest
from test_figures import shrunk_config

from rbstudy.analysis.card_page import scorecard_html
from rbstudy.analysis.conformance import Cell, Verdict
from rbstudy.analysis.findings import findings
from rbstudy.archive.load import open_results
from rbstudy.cli import main
from rbstudy.pipeline.config import load_study
from rbstudy.pipeline.execute import run_study

PNG_URI = "data:image/png;base64,"


@pytest.fixture(scope="module")
def archive(tmp_path_factory):
    folder = tmp_path_factory.mktemp("report")
    return run_study(load_study(shrunk_config("abaqus_top.yaml", folder)), folder / "out", quiet=True).path


class _Page(html.parser.HTMLParser):
    """Images, links, section ids in order, and the text of each figure caption."""

    def __init__(self):
        super().__init__()
        self.images, self.links, self.ids, self.captions = [], [], [], []
        self._caption = None

    def handle_starttag(self, tag, attrs):
        attrs = dict(attrs)
        if tag == "img":
            self.images.append(attrs["src"])
        elif tag == "a":
            self.links.append(attrs["href"])
        elif tag == "figcaption":
            self._caption = []
        if "id" in attrs:
            self.ids.append(attrs["id"])

    def handle_data(self, data):
        if self._caption is not None:
            self._caption.append(data)

    def handle_endtag(self, tag):
        if tag == "figcaption":
            self.captions.append("".join(self._caption))
            self._caption = None


def _parsed(path):
    page = _Page()
    page.feed(path.read_text())
    page.close()
    return page


def _report(archive, out, *options):
    assert main(["report", str(archive), "--out", str(out), *options]) == 0
    return out / "report.html"


@pytest.mark.slow
def test_the_report_is_one_file_with_the_answer_first(archive, tmp_path, capsys):
    report = _report(archive, tmp_path / "report")
    page = _parsed(report)
    drawn = sorted((report.parent / "figures").glob("*.png"))
    assert len(page.images) == len(drawn) > 5
    for source in page.images:  # every image inside the file, a PNG
        assert source.startswith(PNG_URI)
        assert base64.b64decode(source[len(PNG_URI) :])[:8] == b"\x89PNG\r\n\x1a\n"
    # no file beside it is needed: every link is to a place in the page, and without --svg
    # no SVG is written
    assert page.links and all(link.startswith("#") for link in page.links)
    assert {link[1:] for link in page.links} <= set(page.ids)
    assert not list((report.parent / "figures").glob("*.svg"))
    # findings, contents, table, figures, provenance: in that order
    sections = [section for section in page.ids if not section.startswith("figure-")]
    assert sections[:4] == ["findings", "contents", "schemes", "figures"]
    assert sections[-1] == "provenance"
    text = report.read_text()
    found = findings(open_results(archive))
    positions = [text.index(html.escape(finding.text)) for finding in found]
    assert positions == sorted(positions) and positions[-1] < text.index("<table")
    assert text.index("</table>") < text.index("<figure")  # the table before the figures
    assert text.rindex("</figure>") < text.index('id="provenance"') < text.index("history")
    # a caption per figure, none the same, each naming something of this study
    assert len(page.captions) == len(page.images)
    assert len(set(page.captions)) == len(page.captions)
    assert "Fitted orders: hht" in page.captions[0] and "0.01 s" in page.captions[0]


@pytest.mark.slow
def test_svg_files_only_when_asked_for_and_then_linked(archive, tmp_path, capsys):
    report = _report(archive, tmp_path / "report", "--svg")
    page = _parsed(report)
    svgs = [link for link in page.links if link.endswith(".svg")]
    assert len(svgs) == len(page.images)
    assert all((report.parent / link).is_file() for link in svgs)
    assert all(source.startswith(PNG_URI) for source in page.images)


def _progress(capsys):
    """(figures drawn, figures reused), as the end line of the report's progress tells them
    on stderr, which is not a terminal here: a start line and an end line."""
    start, end = capsys.readouterr().err.splitlines()
    assert " writing its report into " in start
    drawn, reused = re.fullmatch(r".*: (\d+) figures? drawn, (\d+) reused in [\d.]+ s", end).groups()
    return int(drawn), int(reused)


@pytest.mark.slow
def test_a_second_report_reuses_its_figures_and_an_edited_archive_redraws(archive, tmp_path, capsys):
    out = tmp_path / "report"
    capsys.readouterr()
    report = _report(archive, out)
    pngs = sorted((out / "figures").glob("*.png"))
    assert _progress(capsys) == (len(pngs), 0)
    drawn = {png: png.stat().st_mtime_ns for png in pngs}
    first = report.read_text()
    _report(archive, out)
    assert _progress(capsys) == (0, len(pngs))
    assert {png: png.stat().st_mtime_ns for png in pngs} == drawn
    assert report.read_text() == first
    # --quiet: nothing on stderr
    _report(archive, out, "--quiet")
    assert capsys.readouterr().err == ""
    # a changed value (the checksums no longer match: read as it is) draws every figure again
    edited = tmp_path / "edited.nc"
    edited.write_bytes(archive.read_bytes())
    with netCDF4.Dataset(edited, "a") as nc:
        error = nc["final_orientation_error"]
        first = (0,) * error.ndim
        error[first] = 1.01 * error[first]
    _report(edited, out, "--no-verify")
    assert _progress(capsys) == (len(pngs), 0)
    assert all(png.stat().st_mtime_ns != drawn[png] for png in pngs)
    # a figure deleted is drawn again (with the figures of its drawing: it alone), the others
    # kept
    deleted = out / "figures" / "abaqus_top_convergence_orientation.png"
    deleted.unlink()
    _report(edited, out, "--no-verify")
    assert _progress(capsys) == (1, len(pngs) - 1)
    assert deleted.is_file()


@pytest.mark.slow
def test_a_report_copies_the_figures_plot_drew_for_the_same_archive(archive, tmp_path, capsys):
    """`report` drew every figure again right after `plot` drew them (15-69 s): it now
    copies those plot recorded beside the archive under the same digest (the archive's
    values and the code that draws), and draws them when the archive changed since."""
    copy = tmp_path / "study" / archive.name
    copy.parent.mkdir()
    copy.write_bytes(archive.read_bytes())
    plotted = copy.parent / "figures"
    capsys.readouterr()
    assert main(["plot", str(copy)]) == 0
    pngs = sorted(plotted.glob("*.png"))
    drawn = {png: png.stat().st_mtime_ns for png in pngs}
    capsys.readouterr()
    out = tmp_path / "report"
    _report(copy, out)
    assert _progress(capsys) == (0, len(pngs))
    copied = sorted((out / "figures").glob("*.png"))
    assert [png.name for png in copied] == [png.name for png in pngs]
    assert all(png.read_bytes() == (plotted / png.name).read_bytes() for png in copied)
    assert {png: png.stat().st_mtime_ns for png in pngs} == drawn  # plot's left as they were
    # the archive changed since plot drew: the report draws them all
    with netCDF4.Dataset(copy, "a") as nc:
        error = nc["final_orientation_error"]
        first = (0,) * error.ndim
        error[first] = 1.01 * error[first]
    _report(copy, out, "--no-verify")
    assert _progress(capsys) == (len(pngs), 0)


@pytest.mark.slow
def test_the_conformance_page_and_the_report_share_one_base_page(archive, tmp_path, capsys):
    report = _report(archive, tmp_path / "report", "--quiet").read_text()
    cell = Cell(
        passed=False,
        value=float("nan"),
        verdicts={"order": Verdict(False, 0.5, "order 0.50 <b>"), "energy": Verdict(None, 0.0, "not judged")},
    )
    page = scorecard_html({"case_a": {"euler": cell}}, ["case_a"], {"case_a": "A & B"}, ["a header line"])
    head = report[: report.index("<title>")]
    assert page.startswith(head) and head.count("viewport") == 1
    base_style = report[report.index("<style>") : report.index("small, .muted")]
    assert base_style in page
    assert "order 0.50 &lt;b&gt;" in page and 'title="A &amp; B"' in page  # escaped
    assert page.count('class="fail"') == 1 and "✗ order" in page and "· energy" in page


def test_a_conformance_table_of_22_schemes_and_12_cases_scrolls_inside_the_page():
    """It was ~3000 px wide in a 1240 px page: the window scrolled, the rules and header with
    it. Now the table sits alone in a box that scrolls both ways within the window."""

    class Parents(html.parser.HTMLParser):
        def __init__(self):
            super().__init__()
            self.open, self.parent = [], None

        def handle_starttag(self, tag, attrs):
            if tag == "table":
                self.parent = self.open[-1] if self.open else None
            self.open.append((tag, dict(attrs).get("class")))

        def handle_endtag(self, tag):
            while self.open and self.open.pop()[0] != tag:
                pass

    verdict = {"order": Verdict(True, 2.0, "observed 2.00 (nominal 2), dt 0.01-0.0025")}
    cases = [f"case_{k}" for k in range(12)]
    cells = {case: {f"scheme_{k}": Cell(True, 2.0, verdict) for k in range(22)} for case in cases}
    page = scorecard_html(cells, cases, {case: case for case in cases}, ["a header line"])
    parser = Parents()
    parser.feed(page)
    tag, box = parser.parent
    assert tag == "div" and box
    style = re.search(rf"div\.{box} {{([^}}]*)}}", page).group(1)
    assert "overflow: auto" in style and "max-width: 100%" in style and "max-height" in style
    assert page.count("<td") == 22 * (12 + 1)  # a cell per case, and the cases passed


@pytest.mark.slow
def test_the_report_of_another_shipped_study_has_distinct_captions(tmp_path, capsys):
    """A one-scheme study (hht's damping swept): lines are the swept option's values."""
    path = run_study(
        load_study(shrunk_config("hht_damping.yaml", tmp_path)), tmp_path / "out", quiet=True
    ).path
    page = _parsed(_report(path, tmp_path / "report", "--quiet"))
    assert len(set(page.captions)) == len(page.captions) > 3
    assert any(re.search(r"a line per alpha \(", caption) for caption in page.captions)


@pytest.mark.slow
def test_a_long_title_heads_the_page_cut_to_a_config_s_bound(archive, tmp_path):
    """An archive made elsewhere may carry a megabyte of title: the page held it whole twice
    (its <title> and <h1>), 7 MB of text covering the answer."""
    from rbstudy.inputs.reader import MAX_TITLE_CHARACTERS

    edited = tmp_path / "long.nc"
    edited.write_bytes(archive.read_bytes())
    with netCDF4.Dataset(edited, "a") as nc:
        nc.setncattr("title", "a top,   spinning " * 60_000)
    page = _report(edited, tmp_path / "report").read_text()
    (heading,) = re.findall(r"<h1>(.*?)</h1>", page, flags=re.S)
    assert len(html.unescape(heading)) <= MAX_TITLE_CHARACTERS and heading.endswith("\u2026")
    assert html.unescape(heading).startswith("a top, spinning a top, spinning")
    assert page.count("spinning") < 100  # of 60,000
