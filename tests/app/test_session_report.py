"""`vbfe report` and `vbfe dataset --report`: self-contained pages with every section, drops and
gaps marked, rendered in headless Chromium when it is installed."""

import json
import re
import shutil
import subprocess

import cv2
import numpy as np
import pytest

from vbfe.acquire import (
    EstimateStream,
    SessionReader,
    SessionWriter,
    finalize_session,
    record_session,
    store_analysis,
    store_estimates,
)
from vbfe.cli.main import main
from vbfe.drivers.samples import ForceSample, StereoFrame
from vbfe.rig_config import builtin_rig
from vbfe.session_report import SECTIONS
from vbfe.truth import calibration_from_rig, true_rig

CHROMIUM = next(
    (
        shutil.which(name)
        for name in ("chromium", "chromium-browser", "google-chrome")
        if shutil.which(name)
    ),
    None,
)


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    """A bench session with calibration, sync verdict, live estimates and clouds, and a
    synthetic one with a force sequence drop and a recorder gap."""
    folder = tmp_path_factory.mktemp("report")
    config = builtin_rig({"bench": dict(width=160, height=90, fps=15.0)})
    calibration = calibration_from_rig(true_rig(config))
    bench = folder / "bench.h5"
    record_session(config, bench, duration_s=2.0, calibration_yaml=calibration.to_yaml_text())
    store_analysis(
        bench,
        {
            "sync_verdict": "pass",
            "sync_offset_s": 0.0012,
            "sync_offset_ci95_low_s": 0.0002,
            "sync_offset_ci95_high_s": 0.0022,
            "sync_protocol": "traction",
            "sync_reasons": json.dumps([]),
        },
    )
    with SessionReader(bench) as reader:
        _, t_host, seq = reader.stream_times("camera")
        force = np.linalg.norm(reader.force_at_frames(), axis=1)
    store_estimates(
        bench,
        EstimateStream(
            force_n=(force + 0.05)[:, None],
            frame_seq=seq,
            t_frame_host_ns=t_host,
            t_ready_host_ns=t_host + 30_000_000,
            stage_s=np.full((len(seq), 1), 0.03),
            stages=["model"],
            attrs={"target": "magnitude", "outputs": 1},
            lo_n=(force - 0.2)[:, None],
            hi_n=(force + 0.3)[:, None],
            ood=np.arange(len(seq)) % 10 == 0,
        ),
    )
    assert main(["reconstruct", str(bench), "--workers", "1", "--no-verify"]) == 0

    gappy = folder / "sub" / "gappy.h5"
    gappy.parent.mkdir()
    writer = SessionWriter(gappy, (64, 48))
    image = np.full((48, 64, 3), 90, np.uint8)
    writer.append_frames(
        [StereoFrame(image, image, i, i * 50_000_000, i * 50_000_000 + 10**9) for i in range(10)]
    )
    kept = [i for i in range(500) if not 200 <= i < 210]  # 10 samples dropped by the device
    writer.append_forces(
        [
            ForceSample(np.array([0.0, 0.0, i / 500]), i, i * 1_000_000, i * 1_000_000 + 10**9)
            for i in kept
        ]
    )
    writer.add_gap("force", "queue full", 300, 301, 10**9 + 300_000_000, 0)
    writer.close()
    finalize_session(gappy, {"end_reason": "test"})
    return folder, bench, gappy


@pytest.fixture(scope="module")
def bench_page(dataset, tmp_path_factory):
    """The report page of the bench session, written once through the CLI."""
    out = tmp_path_factory.mktemp("page") / "bench.html"
    assert main(["report", str(dataset[1]), "-o", str(out)]) == 0
    return out


def _img_sources(page):
    return re.findall(r'<img src="([^"]*)"', page)


def test_session_page_has_every_section_and_is_self_contained(bench_page):
    page = bench_page.read_text()
    for section in SECTIONS[1:]:
        assert f"<h2>{section}</h2>" in page
    sources = _img_sources(page)
    assert sources and all(s.startswith("data:image/") for s in sources)
    assert not re.search(r'(href|src)="(http|/|\.\.)', page)
    assert page.count('<div class="strip">') == 1 and len(sources) == 8 + 4  # thumbs + plots
    assert "Not verified" not in page and '<span class="pass">PASS</span>' in page
    assert "No clouds file" not in page and "median density" in page
    assert re.search(r"30 estimates \(magnitude\); MAE 0\.0[45]\d N", page)
    assert "; 3 estimates from frames outside the training data" in page
    assert "B</td><td>4.0000 mm" in page


def test_stored_estimates_keep_their_interval_and_flag(dataset):
    with SessionReader(dataset[1]) as reader:
        stored = reader.estimates()
    np.testing.assert_allclose(stored.hi_n - stored.lo_n, 0.5)
    np.testing.assert_allclose(stored.force_n - stored.lo_n, 0.25)
    assert stored.ood.dtype == bool and stored.ood.sum() == 3


def test_drops_and_gaps_are_marked(dataset, tmp_path):
    _, _, gappy = dataset
    out = tmp_path / "gappy.html"
    assert main(["report", str(gappy), "-o", str(out)]) == 0
    page = out.read_text()
    assert "1 sequence drops (10 samples), red bands: 1 recorder gaps" in page
    assert "<td>force</td><td>490</td>" in page and "No calibration stored" in page
    assert main(["report", str(gappy), "-o", str(out)]) == 2  # exists, no --overwrite


def test_dataset_report_links_every_session_page(dataset, tmp_path):
    folder, _, _ = dataset
    out = tmp_path / "pages"
    assert main(["dataset", str(folder), "--report", str(out)]) == 0
    index = (out / "index.html").read_text()
    links = re.findall(r'<a href="([^"]+)">([^<]+)</a>', index)
    assert sorted(text for _, text in links) == ["bench.h5", "sub/gappy.h5"]
    for href, _ in links:
        assert "<h2>Force</h2>" in (out / href).read_text()
    assert '<span class="pass">pass</span>' in index


@pytest.mark.skipif(
    CHROMIUM is None,
    reason="Chromium is not installed (apt-get install chromium) - the page is not rendered",
)
def test_page_renders_in_headless_chromium(bench_page, tmp_path):
    shot = tmp_path / "shot.png"
    subprocess.run(
        [
            CHROMIUM,
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--hide-scrollbars",
            f"--screenshot={shot}",
            "--window-size=1100,4000",
            bench_page.as_uri(),
        ],
        check=True,
        capture_output=True,
        timeout=60,
    )
    image = cv2.imread(str(shot))
    assert image.shape[:2] == (4000, 1100)
    rows = np.flatnonzero((image < 200).any(axis=(1, 2)))  # rows with something drawn
    assert rows.max() > 2500  # every section down the page rendered, not just the title
