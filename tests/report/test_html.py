"""index.html, the report as one page: written from a real report folder (a tiny generated
store of the five concepts, tested with a physics-blind scorer through VOEReportCallback), it
shows every concept's verdict, the causality line and four looping videos per concept over
their per-frame surprise, inlines everything (no script, no outside file), and opens from
file:// in headless Chromium without a console error, its images loaded and its videos playing;
``analyze compare --page`` writes the page of several runs."""

import base64
import io
import re
import shutil
import time
from html.parser import HTMLParser
from pathlib import Path

import lightning as L
import numpy as np
import pytest
from helpers import ALPHA
from PIL import Image

from voe_lightning import specs
from voe_lightning.analysis.comparison import compare
from voe_lightning.callbacks import VOEReportCallback
from voe_lightning.data import store
from voe_lightning.datamodules import VOEDataModule
from voe_lightning.model import CueScorer
from voe_lightning.report.page.examples import VIDEOS, choose_quadruplets, read_examples
from voe_lightning.report.page.markdown import markdown_html
from voe_lightning.report.pairs import PairResults

NUM_FRAMES = 8
#: Per surprise plot under a video, as the browser lays it out: its size, its two curves, its
#: texts, the numbers among them, and any text that falls outside the plot's box.
SURPRISE_PLOTS = """
return Array.from(document.querySelectorAll("svg.surprise")).map(svg => {
  const box = svg.getBoundingClientRect();
  const texts = Array.from(svg.querySelectorAll("text"));
  return {
    width: box.width, height: box.height,
    lines: svg.querySelectorAll("polyline").length,
    texts: texts.map(t => t.textContent),
    numbers: texts.map(t => t.textContent).filter(t => !isNaN(parseFloat(t))),
    clipped: texts.filter(t => {
      const r = t.getBoundingClientRect();
      return r.width === 0 || r.left < box.left - 0.5 || r.right > box.right + 0.5
        || r.top < box.top - 0.5 || r.bottom > box.bottom + 0.5;
    }).map(t => t.textContent),
  };
});
"""
#: Chromium's flags on a machine with no network (without them it waits on the network).
CHROMIUM_FLAGS = (
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--window-size=1200,1600",
)


class Elements(HTMLParser):
    """Every element of a page as (tag, attributes), and its text."""

    def __init__(self, page: str):
        super().__init__()
        self.elements: list[tuple[str, dict[str, str | None]]] = []
        self.texts: list[str] = []
        self.feed(page)

    def handle_starttag(self, tag, attrs):
        self.elements.append((tag, dict(attrs)))

    def handle_data(self, data):
        self.texts.append(data)

    def of(self, tag: str, css: str | None = None) -> list[dict[str, str | None]]:
        return [
            attrs
            for name, attrs in self.elements
            if name == tag and (css is None or css in (attrs.get("class") or "").split())
        ]


def frame_count(uri: str) -> int:
    """The frames of an inlined animated image."""
    with Image.open(io.BytesIO(base64.b64decode(uri.partition(",")[2]))) as image:
        return image.n_frames


@pytest.fixture(scope="module")
def report(tmp_path_factory) -> Path:
    """A report of all five concepts: three test quadruplets each (per unchangeableness
    change), 8 frames of 32x32, scored by the pixel-novelty cue; its page written."""
    folder = tmp_path_factory.mktemp("page")
    datamodule = VOEDataModule(
        root=str(folder / "store"),
        train_examples=1,
        val_pairs=1,
        test_pairs=3,
        generalization_pairs=0,
        probe_batch_size=16,
        generate_workers=1,
        num_frames=NUM_FRAMES,
        height=32,
        width=32,
    )
    callback = VOEReportCallback(out_dir=str(folder / "run"), alpha=ALPHA, bootstrap=100)
    trainer = L.Trainer(
        default_root_dir=folder,
        callbacks=[callback],
        logger=False,
        enable_progress_bar=False,
        enable_model_summary=False,
        accelerator="cpu",
    )
    trainer.test(CueScorer("novelty"), datamodule=datamodule)
    assert (callback.report_dir / "index.html").is_file()  # the report writes its page
    return callback.report_dir


def test_the_chosen_quadruplet_is_the_median_one():
    d = {100: (1.0, 2.0), 101: (5.0, 5.0), 102: (-1.0, 0.5), 103: (2.0, 2.0), 104: (9.0, -3.0)}
    seeds = [seed for seed in d for _ in range(2)]
    variants = ["standard", "counterbalanced"] * len(d)
    consistent = np.zeros((len(seeds), 3))
    inconsistent = consistent.copy()
    inconsistent[:, 2] = [half for halves in d.values() for half in halves]
    results = PairResults(
        ["solidity"] * len(seeds), variants, seeds, [1] * len(seeds), consistent, inconsistent
    )
    [chosen] = choose_quadruplets(results)
    # D: 3, 10, -0.5, 4, 6: the median is 4, seed 103's.
    assert (chosen.concept, chosen.seed, chosen.count) == ("solidity", 103, 5)
    assert chosen.variants == ("standard", "counterbalanced")
    assert [results.seed[i] for i in chosen.pairs] == [103, 103]


def test_the_reports_markdown_becomes_tables_lists_and_text():
    text = (
        "## Title\n\n| a | b |\n|---|---|\n| **x** | 1 < 2 |\n\n- one\n- `two`\n\n"
        "*Note*: p < .01, t(9) = 3.1*\n"
    )
    page = markdown_html(text)
    assert "<h3>Title</h3>" in page and "<th>a</th><th>b</th>" in page
    assert "<td><strong>x</strong></td><td>1 &lt; 2</td>" in page
    assert "<ul><li>one</li><li><code>two</code></li></ul>" in page
    assert "<p><em>Note</em>: p &lt; .01, t(9) = 3.1*</p>" in page


@pytest.mark.slow
def test_the_page_shows_each_concepts_verdict_videos_and_the_causality_line(report):
    page = (report / "index.html").read_text()
    elements = Elements(page)
    text = " ".join(" ".join(elements.texts).split())
    assert "causality: per-frame surprise identical before each pair's first difference" in text
    verdict_rows = re.findall(r"<tr><td><strong>(\w+)</strong></td><td><span class=\"badge", page)
    assert verdict_rows == list(specs.CONCEPTS)
    sections = re.findall(r'<section class="quadruplet" data-concept="(\w+)">(.*?)</section>', page)
    assert [concept for concept, _ in sections] == list(specs.CONCEPTS)
    for concept, section in sections:
        videos = Elements(section).of("img", "video")
        assert len(videos) == 4, concept
        assert all(frame_count(video["src"]) == NUM_FRAMES for video in videos)
        assert len(Elements(section).of("svg", "surprise")) == 4
        assert "The change is hidden at frame" in section
        for plot in re.findall(r'<svg class="surprise".*?</svg>', section):
            # axes, a tick per frame, the range's ends, the frame numbers and a legend; the
            # pair's other video dashed, drawn after (over) this one's
            marks = Elements(plot)
            assert len(marks.of("line")) == 2 + NUM_FRAMES + 1 + 2, concept
            words = marks.texts
            assert {"0", str(NUM_FRAMES - 1), "frame", "this video", "its pair's other"} <= set(
                words
            ), words
            solid, dashed = marks.of("polyline")
            assert "stroke-dasharray" in dashed and "stroke-dasharray" not in solid
    for figure in ("histograms.png", "surprise_per_frame.png", "cue_scatter.png"):
        assert f"<code>{figure}</code>" in page
    assert "Cue audit on the model's test pairs" in text
    assert "relative accuracy: sum" in text  # the field's metrics
    # Self-contained: every image inlined, no script, no stylesheet or font from elsewhere.
    assert all(img["src"].startswith("data:image/") for img in elements.of("img"))
    assert not elements.of("script") and not elements.of("link")
    assert not re.search(r"(src|href)=\"(?!data:|#)", page)


@pytest.mark.slow
def test_the_examples_are_the_stores_frames_of_one_quadruplet(report):
    results = PairResults.from_csv(report / "pairs.csv")
    examples = read_examples(report)
    assert [e.concept for e in examples] == list(specs.CONCEPTS)
    for example in examples:
        assert example.variants == specs.VERDICT_VARIANTS[example.concept][:2]
        split = store.open_split(report.parent.parent / "store", example.concept, "test")
        records = {
            (specs.VARIANTS[int(r["variant"])], int(r["seed"])): r
            for r in (split[i] for i in range(len(split)))
        }
        first, second = (records[(v, example.seed)] for v in example.variants)
        frames = example.frames
        assert set(frames) == set(VIDEOS)
        for name, record, side in (
            ("A", first, "consistent"),
            ("AB", first, "inconsistent"),
            ("B", second, "consistent"),
            ("BA", second, "inconsistent"),
        ):
            assert np.array_equal(frames[name], record[side, "frames"].numpy()), name
        change = int(first["manipulation_frame"])
        assert np.array_equal(frames["AB"][: change + 1], frames["A"][: change + 1])
        assert np.array_equal(frames["AB"][change + 1 :], frames["B"][change + 1 :])
        assert example.count == 3 and example.seed in set(results.seed)


def chromium():
    """A headless Chromium driven by Selenium, logging the console; skipped without one."""
    webdriver = pytest.importorskip("selenium.webdriver")
    binary, driver = shutil.which("chromium"), shutil.which("chromedriver")
    if binary is None or driver is None:
        pytest.skip(
            "chromium and chromedriver are not installed (apt-get install chromium chromium-driver)"
        )
    from selenium.webdriver.chrome.service import Service

    options = webdriver.ChromeOptions()
    options.binary_location = binary
    for flag in CHROMIUM_FLAGS:
        options.add_argument(flag)
    options.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    return webdriver, options, Service(driver)


@pytest.mark.slow
def test_the_page_opens_offline_in_a_browser_with_its_videos_playing(report, tmp_path):
    webdriver, options, service = chromium()
    options.add_argument(f"--user-data-dir={tmp_path / 'profile'}")
    browser = webdriver.Chrome(options=options, service=service)
    try:
        browser.set_page_load_timeout(30)
        browser.get((report / "index.html").as_uri())
        loaded = browser.execute_script(
            "return Array.from(document.images).map(i => [i.className, i.complete, i.naturalWidth]);"
        )
        assert len([image for image in loaded if image[0] == "video"]) == 4 * len(specs.CONCEPTS)
        assert all(complete and width > 0 for _, complete, width in loaded), loaded
        video = browser.find_element("css selector", "img.video")
        first = video.screenshot_as_png
        time.sleep(0.7)  # about three frames of 250 ms: the timeline under the frames moves on
        assert video.screenshot_as_png != first
        plots = browser.execute_script(SURPRISE_PLOTS)
        assert len(plots) == 4 * len(specs.CONCEPTS)
        for plot in plots:  # drawn, and every label inside its box where the page shows it
            assert plot["lines"] == 2 and plot["width"] > 0 and plot["height"] > 0, plot
            assert {"this video", "its pair's other", "frame", "change"} <= set(plot["texts"])
            assert "0" in plot["texts"] and len(plot["numbers"]) >= 4, plot  # y ends, frames
            assert plot["clipped"] == [], plot
        assert browser.save_screenshot(str(tmp_path / "index.png"))
        with Image.open(tmp_path / "index.png") as shot:
            assert shot.size[0] >= 1000 and len(shot.getcolors(1 << 24) or []) > 50
        errors = [entry for entry in browser.get_log("browser") if entry["level"] == "SEVERE"]
        assert errors == []
    finally:
        browser.quit()


@pytest.mark.slow
def test_compare_writes_a_page_of_the_runs_side_by_side(report, tmp_path, capsys):
    run = report.parent
    page_path = tmp_path / "compare.html"
    compare([f"novelty={run}", f"novelty={run}"], page=page_path)
    page = page_path.read_text()
    elements = Elements(page)
    headers = re.findall(r"<th>([^<]*)</th>", page.split("</thead>")[0])
    assert headers == ["concept", "novelty", "novelty (2)"]
    for concept in specs.CONCEPTS:
        assert page.count(f"<tr><td><strong>{concept}</strong></td>") == 1
    figures = elements.of("img", "figure")
    assert len(figures) == 2 * len(list(report.glob("*.png")))
    assert all(img["src"].startswith("data:image/png;base64,") for img in figures)
    assert f"wrote {page_path}" in capsys.readouterr().out
