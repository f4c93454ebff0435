"""`zcomp report OUT` (issue 38, item 3): the rows of a real output folder, the page's
escaping, bad input, atomic writing, nothing written outside OUT. The page in a real
browser: test_report_browser.py."""

from __future__ import annotations

import json
import os
import re
import urllib.parse
from html.parser import HTMLParser
from pathlib import Path

import pytest
from click.testing import CliRunner

from report_project import HOSTILE_NAME, HOSTILE_REASON, add_hostile_failure, add_previews, make_output
from zcomp_cli.cli import cli
from zcomp_cli.errors import OutputError
from zcomp_cli.report import collect, light_summary, write_report
from zcomp_cli.report.synthetic import make_output_folder


def _run(*args):
    return CliRunner().invoke(cli, list(map(str, args)))


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    """(manifest, out) of a real composite + eval run; tests copy it before changing it."""
    return make_output(tmp_path_factory.mktemp("report"))


@pytest.fixture
def project(built, tmp_path):
    """A private copy of the built project and output folder (the reports name the
    manifest by its absolute path: the copy's reports are pointed at the copy's)."""
    import shutil

    src_root = built[1].parent
    shutil.copytree(src_root, tmp_path / "r", symlinks=True)
    root = tmp_path / "r"
    old, new = str(src_root / "project"), str(root / "project")
    for rep in (root / "out").glob("*/report.json"):
        rep.write_text(rep.read_text().replace(json.dumps(old)[1:-1], json.dumps(new)[1:-1]))
    return root / "project" / "jobs.yaml", root / "out"


def _tree(root: Path, skip: Path | None = None) -> dict[str, tuple[int, int]]:
    got = {}
    for dirpath, dirnames, filenames in os.walk(root):
        if skip is not None and Path(dirpath) == skip:
            dirnames[:] = []
            continue
        for f in filenames:
            p = Path(dirpath) / f
            st = p.lstat()
            got[str(p.relative_to(root))] = (st.st_size, st.st_mtime_ns)
    return got


def _blob(page: str) -> dict:
    """The page's embedded JSON document."""
    m = re.search(r'<script id="zcomp-data" type="application/json">(.*?)</script>', page, re.S)
    assert m, "no data blob"
    return json.loads(m.group(1))


def _rows(page: str) -> list[dict]:
    doc = _blob(page)
    keys = [c["key"] for c in doc["columns"]] + doc["extra"]
    return [dict(zip(keys, r)) for r in doc["rows"]]


# ------------------------------------------------------------------ collecting rows
def test_rows_of_a_real_output_folder(project):
    manifest, out = project
    col = collect(out)
    rows = {r["job"]: r for r in col.rows}
    assert set(rows) == {"job000", "job001", "job002", "job003", "job004", "job_ball"}
    assert col.counts == {"done": 5, "failed": 1}
    failed = rows["job_ball"]
    # the reason `zcomp status` gives; scene and object from the manifest (no report)
    assert failed["status"] == "failed" and "depth.exr" in failed["reason"] and "OpenEXR" in failed["reason"]
    assert (failed["scene"], failed["object"], failed["composite"]) == ("s0", "ball", None)
    done = rows["job001"]
    assert done["status"] == "done" and done["reason"] is None
    assert (done["scene"], done["object"], done["renderer"]) == ("s1", "card", "physical")
    assert done["composite"] == out / "job001" / "composite.png"
    assert done["background"] == manifest.parent / "floor1.png"
    assert re.match(r"sun at azimuth \d+°, elevation -?\d+°, estimated from the photograph, ±\d+°",
                    done["light"]), done["light"]
    # the close-up: the re-shaded region, grown, inside the composite's frame
    x0, y0, x1, y1, W, H = done["closeup"]
    assert 0 <= x0 < x1 <= W and 0 <= y0 < y1 <= H and (W, H) == (160, 120)
    assert done["seconds"] > 0
    # eval metrics joined for every finished job, none for the failed one
    ev = json.loads((out / "eval.json").read_text())
    assert col.metrics == ["psnr", "mae"]
    for img in ev["images"]:
        assert rows[img["name"]]["metrics"] == pytest.approx({"psnr": img["psnr"], "mae": img["mae"]})
    assert failed["metrics"] == {}
    assert col.evaluation["joined"] == 5 and col.previews == []


def test_missing_jobs_of_a_manifest(project):
    import yaml

    manifest, out = project
    doc = yaml.safe_load(manifest.read_text())
    doc["jobs"].append({"output": "never_run", "scene": "s2", "object": "card",
                        "placement": {"pixel": [80, 100], "height": 0.2}})
    (manifest.parent / "more.yaml").write_text(yaml.safe_dump(doc, sort_keys=False))
    rows = {r["job"]: r for r in collect(out, manifest=manifest.parent / "more.yaml").rows}
    assert rows["never_run"]["status"] == "missing" and rows["never_run"]["scene"] == "s2"
    assert rows["never_run"]["background"] == manifest.parent / "floor2.png"


def test_manifest_no_longer_valid_still_gives_backgrounds(project):
    manifest, out = project
    manifest.write_text(manifest.read_text().replace("version: 1", "version: 1\nbogus_key: 3"))
    col = collect(out)
    rows = {r["job"]: r for r in col.rows}
    assert rows["job002"]["background"] == manifest.parent / "floor2.png"
    assert any("is not valid now" in n and "bogus_key" in n for n in col.notes), col.notes
    page = write_report(out)[0].read_text()
    assert "is not valid now" in page  # the notes are listed on the page


def test_light_summary():
    from zcomp_cli.worldframe import direction_from_angles

    up = [0.0, 0.93, 0.37]
    d = direction_from_angles(120, 35, up).tolist()
    light = {"source": "estimated", "shadow": "cast shadow", "up_camera": up, "direction": d,
             "lights": [{"kind": "sun"}, {"kind": "sky"}], "fallback": None,
             "fit": {"direction_uncertainty_deg": 12.2, "unfixed": False}}
    rep = {"renderer": {"info": {"light": light}}}
    assert light_summary(rep) == ("sun at azimuth 120°, elevation 35°, estimated from the photograph, ±12°", None,
                                  12.2)
    light.update(fallback="the photograph does not fix the light", shadow="contact shadow only")
    light["fit"]["unfixed"] = True
    text, note, _ = light_summary(rep)
    assert text.endswith("±12°, direction a guess (the photograph does not fix it), contact shadow only, "
                         "simplified (hover for why)")
    assert note == "the photograph does not fix the light"
    light["fit"]["modes"] = [{"kind": "sun", "toward": d, "share": 0.3}, {"kind": "sun", "toward": d, "share": 0.2}]
    assert "direction a guess (the photograph does not fix it): drawn as its 2 likeliest lights" in light_summary(rep)[0]
    assert light_summary({"renderer": {"info": {}}}) == (None, None, None)  # naive, zerocomp
    assert light_summary({"light": {"lights": [{"kind": "sky"}], "source": "manifest"}})[0] == \
        "sky only, given in the manifest"


# ------------------------------------------------------------------ the page
def test_cli_writes_the_page_inside_out_only(project):
    manifest, out = project
    add_previews(out, manifest)
    root = out.parent
    before_out, before_rest = _tree(out), _tree(root, skip=out)
    r = _run("report", out, "--page-size", "2", "--title", "My <run> & co")
    assert r.exit_code == 0, r.output
    assert f"Wrote {out / 'report.html'}: 6 jobs (5 done, 1 failed)" in r.output
    assert "3 preview sheets" in r.output
    assert _tree(root, skip=out) == before_rest  # nothing written outside OUT
    after = _tree(out)
    assert set(after) - set(before_out) == {"report.html"}
    assert all(after[k] == v for k, v in before_out.items())
    page = (out / "report.html").read_text()
    assert "<title>My &lt;run&gt; &amp; co</title>" in page
    assert _blob(page)["pageSize"] == 2
    # every image link is relative and leads to the file (from file://, with ../)
    rows = {r["job"]: r for r in _rows(page)}
    for job, row in rows.items():
        for key in ("composite", "background"):
            if row[key] is None:
                continue
            assert not re.match(r"^[a-z]+:", row[key]) and not row[key].startswith("/"), row[key]
            assert (out / urllib.parse.unquote(row[key])).resolve().is_file()
    assert rows["job000"]["background"] == "../project/floor0.png"
    assert rows["job_ball"]["composite"] is None and rows["job_ball"]["reason"].endswith("not an OpenEXR file")
    assert rows["job001"]["m:psnr"] > 20 and rows["job_ball"]["m:psnr"] is None
    for scene in ("s0", "s1", "s2"):
        assert f'src="preview/{scene}.png"' in page and f'href="preview/{scene}.json"' in page
    assert page.count('<span class="meta">sun at azimuth ') == 3  # each sheet's light, from its .json
    # no external resource: every src/href is relative, a fragment or data:
    for url in re.findall(r'(?:src|href)="([^"]*)"', page):
        assert not re.match(r"^(https?:|//)", url), url


class _Scripts(HTMLParser):
    def __init__(self):
        super().__init__()
        self.scripts, self.tags, self._in = [], [], None

    def handle_starttag(self, tag, attrs):
        self.tags.append(tag)
        if tag == "script":
            self._in = dict(attrs)
            self.scripts.append([self._in, ""])

    def handle_endtag(self, tag):
        if tag == "script":
            self._in = None

    def handle_data(self, data):
        if self._in is not None:
            self.scripts[-1][1] += data


def test_hostile_job_name_and_reason_are_escaped(project):
    manifest, out = project
    add_hostile_failure(out)
    path, col = write_report(out, title="<script>alert(1)</script>")
    assert any(r["job"] == HOSTILE_NAME and r["reason"] == HOSTILE_REASON for r in col.rows)
    page = path.read_text()
    # the text never appears as markup: one data blob and one script, nothing else
    parser = _Scripts()
    parser.feed(page)
    assert [s[0].get("id") for s in parser.scripts] == ["zcomp-data", None]
    assert "img" not in parser.tags and page.count("</script>") == 2
    assert HOSTILE_NAME not in page and "<img src=x" not in page and "</table>" not in page.split("</table>", 1)[1]
    assert "<script>alert(1)</script>" not in page and "&lt;script&gt;alert(1)&lt;/script&gt;" in page
    rows = {r["job"]: r for r in _rows(page)}
    assert rows[HOSTILE_NAME]["reason"] == HOSTILE_REASON and rows[HOSTILE_NAME]["status"] == "failed"
    blob = re.search(r'application/json">(.*?)</script>', page, re.S).group(1)
    assert "<" not in blob and ">" not in blob and "&" not in blob


def test_eval_csv_when_there_is_no_eval_json(project):
    manifest, out = project
    ev = json.loads((out / "eval.json").read_text())
    (out / "eval.json").unlink()
    rows = {r["job"]: r for r in collect(out).rows}
    for img in ev["images"]:
        assert rows[img["name"]]["metrics"]["psnr"] == pytest.approx(img["psnr"], rel=1e-4)
    r = _run("report", out, "--eval", out / "nope.json")
    assert r.exit_code == 2 and "--eval" in r.output


def test_exr_background_becomes_a_thumbnail_inside_out(tmp_path):
    import numpy as np

    from zcomp_cli.imageio import write_exr

    out = make_output_folder(tmp_path, 12, n_scenes=2)
    proj = tmp_path / "project"
    write_exr(proj / "scene0.exr", np.full((60, 80, 3), 0.4, np.float32))
    (proj / "jobs.yaml").write_text((proj / "jobs.yaml").read_text().replace("scene0.png", "scene0.exr"))
    before_rest = _tree(tmp_path, skip=out)
    path, col = write_report(out)
    assert _tree(tmp_path, skip=out) == before_rest
    rows = {r["job"]: r for r in _rows(path.read_text())}
    thumbs = sorted((out / "report_thumbs").iterdir())
    assert len(thumbs) == 1 and thumbs[0].suffix == ".png"
    assert rows["00000_scene0_card"]["background"] == f"report_thumbs/{thumbs[0].name}"
    assert rows["00001_scene1_card"]["background"] == "../project/scene1.png"
    assert col.counts == {"done": 11, "failed": 1}  # one in ten failed (job 9)


# ------------------------------------------------------------------ bad input
@pytest.mark.parametrize("case", ["missing", "file", "empty", "foreign"])
def test_not_an_output_folder_is_a_usage_error(tmp_path, case):
    target = tmp_path / "x"
    if case == "file":
        target.write_text("hello")
    elif case == "empty":
        target.mkdir()
    elif case == "foreign":
        (target / "photos").mkdir(parents=True)
        (target / "notes.txt").write_text("not zcomp")
    before = _tree(tmp_path)
    r = _run("report", target)
    assert r.exit_code == 2, r.output
    msg = r.output.strip()
    assert msg.startswith("Error: ") and len(msg.splitlines()) == 1 and "Traceback" not in msg
    expect = {"missing": "does not exist", "file": "is not a folder", "empty": "is empty",
              "foreign": "not a zcomp output folder"}[case]
    assert expect in msg and str(target) in msg
    assert _tree(tmp_path) == before


@pytest.mark.parametrize("args, needle", [(["--name", "../up.html"], "--name"), (["--name", "a/b.html"], "--name"),
                                          (["--name", "page.txt"], "--name"), (["--page-size", "0"], "page-size")])
def test_bad_options_are_usage_errors(tmp_path, args, needle):
    out = make_output_folder(tmp_path, 3)
    r = _run("report", out, *args)
    assert r.exit_code == 2 and needle in r.output, r.output
    assert not list(tmp_path.rglob("*.html")) and not list(tmp_path.rglob("up.html"))


def test_page_is_written_atomically(tmp_path, monkeypatch):
    """A write that fails half way leaves the previous page whole and no temporary."""
    out = make_output_folder(tmp_path, 5)
    path, _ = write_report(out)
    old = path.read_bytes()
    import zcomp_cli.imageio as zio

    real_fsync = os.fsync

    def failing_fsync(fd):
        real_fsync(fd)
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(zio.os, "fsync", failing_fsync)
    with pytest.raises(OutputError, match="No space left"):
        write_report(out, title="new title")
    assert path.read_bytes() == old
    assert sorted(p.name for p in out.iterdir() if p.is_file()) == ["eval.json", "report.html", "summary.json"]
    r = _run("report", out)  # the CLI: a one-line error, exit 1, still no temporary
    assert r.exit_code == 1 and "No space left" in r.output
    assert path.read_bytes() == old
    assert not [p for p in out.iterdir() if p.name.startswith(".")]


def test_synthetic_folder_pages(tmp_path):
    out = make_output_folder(tmp_path, 250, n_scenes=4)
    path, col = write_report(out, page_size=100)
    doc = _blob(path.read_text())
    assert len(doc["rows"]) == 250 and doc["pageSize"] == 100
    assert col.counts == {"done": 225, "failed": 25}
    assert col.metrics == ["psnr", "ssim", "lpips", "flip"]
    assert sum(1 for r in col.rows if r["metrics"]) == 125  # eval.json scores every even job (all done)


class _Attrs(HTMLParser):
    def __init__(self):
        super().__init__()
        self.attrs: list[tuple[str, str, str | None]] = []
        self.metas: list[dict] = []

    def handle_starttag(self, tag, attrs):
        self.attrs += [(tag, k, v) for k, v in attrs]
        if tag == "meta":
            self.metas.append(dict(attrs))


def test_the_template_is_filled_in_one_pass(tmp_path):
    """Issue 50, defect 1: a preview named ``%DATA%.png`` pulled the whole JSON into
    its image's ``alt`` (chained replaces), so `` onload=CODE `` in any text became a
    handler. Now every slot is filled once, the data's quotes are escaped and the
    policy allows the page's one script by its nonce, no inline handler."""
    from report_project import HANDLER, SLOTS, make_slot_named_output

    out = make_slot_named_output(tmp_path)
    path, col = write_report(out, title="t %DATA% %JS% %NONCE%")
    page = path.read_text()
    p = _Attrs()
    p.feed(page)
    assert [a for a in p.attrs if a[1].startswith("on")] == []
    alts = sorted(v for t, k, v in p.attrs if t == "img" and k == "alt")
    assert alts == sorted(f"preview of {s}" for s in SLOTS)
    csp = next(m["content"] for m in p.metas if m.get("http-equiv") == "Content-Security-Policy")
    nonce = re.search(r"script-src 'nonce-([A-Za-z0-9_-]{16,})'", csp).group(1)
    assert "unsafe-inline" not in csp.split("script-src", 1)[1]
    assert [v for t, k, v in p.attrs if t == "script" and k == "nonce"] == [nonce]
    assert "<title>t %DATA% %JS% %NONCE%</title>" in page
    blob = re.search(r'application/json">(.*?)</script>', page, re.S).group(1)
    assert '\\"' not in blob
    rows = {r["job"]: r for r in _rows(page)}
    assert HANDLER in rows['q"uote' + HANDLER]["reason"] and set(rows) == {"job" + HANDLER, 'q"uote' + HANDLER,
                                                                          "plain"}
