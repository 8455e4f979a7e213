"""The HTML report opened in headless Chromium: every section there, every plot rendered."""

import json
import shutil
import subprocess
import tempfile
from pathlib import Path

import numpy as np
import pytest
import qh_required
import qh_runs as _runs

from quickhealth.station.archive import Archive
from quickhealth.station.cli import main
from quickhealth.station.reporting.figures import joint_figure, shared_limits, trend_figure
from quickhealth.station.reporting.iso9283 import iso9283_pose_stats

CHROMIUM = Path("/usr/bin/chromium")
CHROMEDRIVER = Path("/usr/bin/chromedriver")
FLAGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--window-size=1280,800",  # the first screen a reader sees
]
SECTIONS = [
    "verdict",
    "summary",
    "calibration",
    "coverage",
    "workspace",
    "curves",
    "residuals",
    "diagnosis",
    "trend",
    "iso9283",
]


@pytest.fixture(scope="module")
def archived(tmp_path_factory):
    """Three archived runs of one robot; the last has repeated poses, a degraded joint 2 and a
    cyclic error of joint 1 (9 per turn) its model does not have: a candidate that matters."""
    base = tmp_path_factory.mktemp("rep")
    a = Archive.open(base / "arch")
    for i in range(3):
        d = _runs.make_run(
            base / f"r{i}",
            i,
            n_poses=40,
            repeats=3 if i == 2 else 0,
            degrade={"j2.ex.c0": 4e-4} if i == 2 else None,
            time_utc=f"2026-0{i + 1}-01T08:00:00Z",
            effects={"cyclic:j1:h9": 2e-4} if i == 2 else None,
        )
        a.add_run("ur5-a", d)
    return a


def _browser_query(page: Path) -> dict:
    """Open the page in headless Chromium; return what the DOM says about plots and sections."""
    script = """
        const imgs = Array.from(document.querySelectorAll('img.plot'));
        return JSON.stringify({
          imgs: imgs.map(i => ({id: i.id, complete: i.complete, w: i.naturalWidth, h: i.naturalHeight})),
          sections: Array.from(document.querySelectorAll('section')).map(s => s.id),
          missing: Array.from(document.querySelectorAll('.missing')).map(m => m.textContent),
          json: Object.keys(JSON.parse(document.getElementById('report-json').textContent).sections),
          external: Array.from(document.querySelectorAll('[src]')).filter(
              e => !e.getAttribute('src').startsWith('data:')).length,
          first_screen: ['verdict-line', 'verdict-1', 'verdict-2'].map(id => {
              const el = document.getElementById(id);
              const r = el.getBoundingClientRect();
              return {id: id, text: el.textContent, top: r.top, bottom: r.bottom,
                      right: r.right, visible: r.height > 0};
          }),
          verdict_texts: Array.from(document.querySelectorAll('#verdict p')).map(p => p.textContent),
          viewport: [window.innerWidth, window.innerHeight],
          folded: Array.from(document.querySelectorAll('#diagnosis details')).map(
              d => ({open: d.open, rows: d.querySelectorAll('tr').length})),
        });
    """
    profile = tempfile.mkdtemp(prefix="qh-chromium-")
    try:
        try:
            from selenium import webdriver
            from selenium.webdriver.chrome.service import Service
        except ImportError:
            webdriver = None
        if webdriver is not None and CHROMEDRIVER.exists():
            opts = webdriver.ChromeOptions()
            opts.binary_location = str(CHROMIUM)
            for f in [*FLAGS, f"--user-data-dir={profile}"]:
                opts.add_argument(f)
            drv = webdriver.Chrome(service=Service(str(CHROMEDRIVER)), options=opts)
            try:  # the viewport itself 1280x800 (the window size includes the browser's frame)
                drv.execute_cdp_cmd(
                    "Emulation.setDeviceMetricsOverride",
                    {"width": 1280, "height": 800, "deviceScaleFactor": 1, "mobile": False},
                )
                drv.get(page.as_uri())
                return json.loads(drv.execute_script(script))
            finally:
                drv.quit()
        # no selenium: let the page write the answer into its DOM, then dump the DOM
        probe = page.with_name("probe.html")
        probe.write_text(
            page.read_text().replace(
                "</body>",
                "<script>window.addEventListener('load',()=>{const r=(()=>{"
                + script
                + "})();document.body.setAttribute('data-probe',r);});</script></body>",
            )
        )
        out = subprocess.run(
            [
                str(CHROMIUM),
                *FLAGS,
                f"--user-data-dir={profile}",
                "--virtual-time-budget=5000",
                "--dump-dom",
                probe.as_uri(),
            ],
            capture_output=True,
            text=True,
            timeout=60,
            check=True,
        ).stdout
        import html
        import re

        m = re.search(r'data-probe="([^"]*)"', out)
        assert m, "Chromium did not run the probe script"
        return json.loads(html.unescape(m.group(1)))
    finally:
        shutil.rmtree(profile, ignore_errors=True)


@pytest.fixture(scope="module")
def reported(archived):
    """``quickhealth report`` on the degraded run: its folder with report.html and report.json."""
    rec = archived.runs("ur5-a")[-1]
    d = archived.folder(rec)
    argv = ["report", str(d), "--archive", str(archived.root), "--robot", "ur5-a"]
    assert main([*argv, "--threshold-mm", "5"]) == 0
    return d


@pytest.mark.slow
def test_report_renders_every_plot_in_chromium(reported):
    if not CHROMIUM.exists():
        qh_required.unavailable(
            "headless Chromium not installed (/usr/bin/chromium missing): "
            "apt-get install -y chromium chromium-driver"
        )
    page = reported / "report.html"
    dom = _browser_query(page)
    assert dom["sections"] == SECTIONS
    assert dom["missing"] == []
    assert dom["external"] == 0  # self-contained
    assert sorted(dom["json"]) == sorted(SECTIONS)
    # the first 1280x800 screen holds the verdict line, the TCP error against the spec and
    # the run against its baseline
    w, h = dom["viewport"]
    assert (w, h) == (1280, 800), dom["viewport"]
    line, err, base = dom["first_screen"]
    for el in (line, err, base):
        assert el["visible"] and 0 <= el["top"] and el["bottom"] <= h and el["right"] <= w, el
    assert line["text"].startswith("FLAGGED: the robot changed since its baseline: "), line
    assert "mean" in err["text"] and "max" in err["text"] and "spec of 5 mm" in err["text"], err
    assert base["text"].startswith("changed since the baseline run r0"), base
    # the candidate that matters is named; the rest are folded away (one closed <details>)
    assert "top missing effect: cyclic:j1:h9" in dom["verdict_texts"], dom["verdict_texts"]
    assert [(d["open"], d["rows"] > 2) for d in dom["folded"]] == [(False, True)], dom["folded"]
    # coverage, histogram, 6 joints' curves, residuals, trend, ISO 9283
    want = {"plot-coverage", "plot-workspace_hist", "plot-residuals", "plot-trend", "plot-iso9283"}
    want |= {"plot-workspace_map", "plot-calibration"}
    want |= {f"plot-curves_j{j}" for j in range(1, 7)}
    assert {i["id"] for i in dom["imgs"]} == want
    for i in dom["imgs"]:
        assert i["complete"] and i["w"] > 100 and i["h"] > 100, i


@pytest.mark.slow
def test_report_command_extends_report_json(reported):
    doc = json.loads((reported / "report.json").read_text())
    assert doc["n_poses"] == 55 and "workspace" in doc  # the fit's keys stay
    tr = doc["trend"]
    assert tr["flagged"] is True and tr["baseline"] == "r0"
    # j2.ex.c0 twists link 2: the axis of joint 3 tilts about x, named as that fault
    assert any(h.startswith("joint 3 tilt about x changed by +") for h in tr["hints"]), tr
    assert [c["fault"] for c in tr["changes"]] == ["j3.tilt_x"], tr["changes"]
    assert {p["pose_id"] for p in doc["iso9283"]["poses"]} == {f"P{i:03d}" for i in range(5)}
    assert all(p["n"] == 4 and p["rp_mm"] < 0.3 for p in doc["iso9283"]["poses"])
    iso = doc["iso9283"]  # a 7D run: orientation accuracy and repeatability too
    assert iso["orientation"] is True
    assert all(len(p["ap_abc_mrad"]) == 3 and len(p["rp_abc_mrad"]) == 3 for p in iso["poses"])
    assert all(0 < v < 1.0 for p in iso["poses"] for v in p["rp_abc_mrad"])  # noise 0.1 mrad
    assert doc["diagnosis"]["verdict"] in ("adequate", "missing-effect")
    assert len(doc["coverage"]["range_share"]) == 6


@pytest.mark.slow
def test_diagnosis_shows_the_candidate_that_matters_and_folds_the_rest(reported):
    import html
    import re

    doc = json.loads((reported / "report.json").read_text())
    cands = doc["diagnosis"]["candidates"]
    page = (reported / "report.html").read_text()
    sec = page[page.index('<section id="diagnosis">') :]
    sec = sec[: sec.index("</section>")]
    shown_part, _, folded_part = sec.partition("<details>")
    assert "<details open" not in sec and folded_part  # folded, and closed

    def rows(part: str) -> list[tuple[str, str]]:
        return [
            (html.unescape(e), html.unescape(ev))
            for e, ev in re.findall(
                r"<tr><td>(.*?)</td><td>.*?</td><td>.*?</td><td>(.*?)</td>", part
            )
        ]

    shown, folded = rows(shown_part), rows(folded_part)
    # both non-empty: the hidden cyclic error is shown, the side harmonics are folded
    assert [e for e, _ in shown] == ["cyclic:j1:h9"]
    assert {e for e, _ in shown} == {c["effect"] for c in cands if c["significant"]}
    assert {e for e, _ in folded} == {c["effect"] for c in cands if not c["significant"]}
    kinds = {ev.split(" (")[0].split(":")[0] for _, ev in folded}
    assert "detectable but too small to matter" in kinds, kinds  # the case the fold is for
    assert f"{len(folded)} candidates too small to matter or not significant" in folded_part


def test_motions_the_data_cannot_identify_are_labelled_not_identifiable(tmp_path):
    from quickhealth.identify.errormodel import MOTIONS
    from quickhealth.identify.workspace import all_joint_curves
    from quickhealth.station import formats

    # constant (order 0) error motions: a joint's dz and ez constants are not identifiable
    # (they are the next joint's, or the base's), the rest are
    d = _runs.make_run(tmp_path / "r", 0, n_poses=30, order=0, light=True)
    fm = formats.read_model(d / "model.json")
    states = {"not identifiable": 0, "drawn": 0}
    curves = all_joint_curves(fm, n_points=21)
    lim = shared_limits(curves)
    for c in curves:
        fig = joint_figure(c, fm, lim)
        for m, ax in enumerate(fig.axes):
            label = f"j{c.joint}.{MOTIONS[m]}.c0"
            texts = [t.get_text() for t in ax.texts]
            if label in fm.unidentifiable:
                # said in words on a grey panel, no flat zero line, no band
                assert texts == ["not identifiable"] and not ax.lines and not ax.collections
                states["not identifiable"] += 1
            else:
                # the variation about the offset and the zero line, with its band
                assert texts == [] and len(ax.lines) == 2 and len(ax.collections) == 1, label
                band = ax.collections[0].get_paths()[0].vertices[:, 1]
                assert np.ptp(band) > 0, label  # a band with a width
                # every joint on one scale per kind: mm for translations, mrad for rotations
                assert ax.get_ylim() == (-lim[m >= 3], lim[m >= 3]), label
                assert "offset" in ax.get_title(), label
                states["drawn"] += 1
    assert states["not identifiable"] >= 6 and states["drawn"] >= 12, states


@pytest.mark.parametrize("n_runs", [2, 3])
def test_control_chart_stays_readable_with_few_runs(n_runs):
    from quickhealth.identify.trend import RunState, assess_trend

    # a UR5's workspace figures over three monthly runs, the third after a crash: with so few
    # runs the limit's σ comes from the runs' own jump and climbs far above the data
    history = [
        {"mean": 0.21, "std": 0.08, "max": 0.52},
        {"mean": 0.22, "std": 0.08, "max": 0.55},
        {"mean": 1.05, "std": 0.46, "max": 2.61},
    ]
    if n_runs == 2:
        history = [history[0], history[2]]
    runs = [RunState(f"r{i}", 1.77e9 + i * 30 * 86400.0, f) for i, f in enumerate(history)]
    res = assess_trend(runs, 0)
    fig = trend_figure(res)
    climbed = 0
    for ax, f in zip(fig.axes, ("mean", "std", "max"), strict=True):
        seen = [*res.figures_mm[f], *res.charts[f].ewma_mm]
        lo, top = ax.get_ylim()
        assert lo == 0.0 and max(seen) < top <= 1.35 * max(seen) + 1e-12, (f, top)  # all in view
        ucl = max(res.charts[f].ucl_mm)
        if ucl > top:  # the limit is off the axis: said in words with its value
            climbed += 1
            assert [t.get_text() for t in ax.texts] == [
                f"control limit up to {ucl:.2f} mm (few runs: σ not yet known)"
            ]
    assert climbed >= 1  # the case the axis rule is for


def test_iso9283_figures_of_repeated_poses():
    import numpy as np

    ids = ("A", "B", "A", "A", "B", "C")
    cmd = np.zeros((6, 3))
    att = np.array([[1, 0, 0], [0, 0, 0], [1, 0.2, 0], [1, -0.2, 0], [0, 0, 0.1], [5, 5, 5]]) * 1e-3
    st = iso9283_pose_stats(ids, att, cmd)
    assert [s.pose_id for s in st] == ["A", "B"]  # C visited once
    a = st[0]
    assert a.n == 3 and a.accuracy == pytest.approx(1e-3)
    l = np.array([0.0, 0.2, 0.2]) * 1e-3
    assert a.repeatability == pytest.approx(l.mean() + 3 * l.std(ddof=1))


def test_iso9283_orientation_figures_of_repeated_poses():
    """Known rotations about the robot base's axes, seen in a frame rotated against the base:
    AP a/b/c is the mean deviation from the commanded orientation about the base's x/y/z
    (ISO 9283 §7.2.1), RP a/b/c three sample standard deviations (§7.2.3)."""
    import numpy as np

    from quickhealth.identify.transforms import exp_so3, rot_x, rot_z

    R_meas_base = rot_z(0.7) @ rot_x(-0.4)  # the base's axes in the measurement frame
    R_cmd_base = rot_x(0.3) @ rot_z(1.1)  # commanded orientation, base frame
    dev = np.array([[1.0, 0.0, -2.0], [1.2, 0.5, -2.0], [0.8, -0.5, -2.0]]) * 1e-3  # a, b, c
    R_att = exp_so3(dev @ R_meas_base.T) @ (R_meas_base @ R_cmd_base)  # about base axes
    R_cmd = np.broadcast_to(R_meas_base @ R_cmd_base, (3, 3, 3))
    pos = np.zeros((3, 3))
    (st,) = iso9283_pose_stats(("A", "A", "A"), pos, pos, R_att, R_cmd, R_meas_base)
    np.testing.assert_allclose(st.accuracy_abc, [1e-3, 0.0, -2e-3], atol=1e-9)
    np.testing.assert_allclose(st.repeatability_abc, 3 * dev.std(axis=0, ddof=1), atol=1e-9)
    assert st.repeatability_abc[2] == pytest.approx(0.0, abs=1e-9)
    # without the base's axes the components are about the measurement frame's: they differ
    (st_m,) = iso9283_pose_stats(("A", "A", "A"), pos, pos, R_att, R_cmd)
    assert np.abs(st_m.accuracy_abc - st.accuracy_abc).max() > 2e-4
    (st_p,) = iso9283_pose_stats(("A", "A", "A"), pos, pos)  # position-only data
    assert st_p.accuracy_abc is None and st_p.repeatability_abc is None


def test_report_command_without_model_is_one_line_error(tmp_path, capsys):
    assert main(["report", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no model.json" in err[0]


def test_the_report_has_a_one_page_pdf_beside_it(reported):
    """report.pdf: one A4 page (matplotlib), the verdict's words on it."""
    pdf = (reported / "report.pdf").read_bytes()
    assert (
        pdf.startswith(b"%PDF-") and pdf.count(b"/Type /Page\n") + pdf.count(b"/Type /Page ") >= 1
    )
    assert b"/Count 1" in pdf  # one page
    assert b"/MediaBox [ 0 0 595.44 841.68 ]" in pdf  # A4 portrait
