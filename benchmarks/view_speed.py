"""``pgd view`` pages of the shipped codebooks in headless Chromium: load, console errors, time per slider move.

    python benchmarks/view_speed.py                       # codebooks/<name>.h5, solved where missing
    python benchmarks/view_speed.py --dir /tmp/cb --problems spring,coupled
    python benchmarks/view_speed.py --no-solve            # only the codebooks already in --dir

For every problem in problems/ (its codebook read from ``--dir``, default codebooks/, or solved
there first), the page is written (``--force`` past the size limit, said in the table) and opened
in Debian's headless Chromium through Selenium, then measured by the page itself
(``window.pgdView.bench``): after a move of the first parameter's slider,

- **curves**: the curves of every unknown at 400 samples recomputed, the work a slider move costs,
  against the 16.7 ms of one animation frame at 60 Hz: the mean of 10 recomputations (the
  browser's clock ticks in 0.1 ms) after each of 40 moves, the least of the 40 (the cost without
  the waits of a shared machine) and the median;
- **update**: the whole update without the map (curves, charts, values), and **map**: the
  field over space redrawn (drawn after the frame when it takes longer than one).

Beside them, in the same run: the same curves by ``Codebook.evaluate_series`` in Python (numpy,
one call for all 400 samples and every unknown), the alternative a notebook user has, measured
the same way (blocks of 10 calls, the least and the median of 40). The load time
is from navigation to the page's first update. Console errors and warnings are counted (any is a
defect). Prints a Markdown table (docs/view.md quotes it); ``--output FILE`` also writes it.
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from _machine import markdown_table, report  # benchmarks/ is on sys.path

ROOT = Path(__file__).resolve().parents[1]
FRAME_MS = 1000 / 60


def start_browser(profile: str):
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    options = webdriver.ChromeOptions()
    options.binary_location = shutil.which("chromium") or shutil.which("chromium-browser")
    for arg in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage", "--disable-quic",
                "--no-first-run", "--disable-background-networking", "--disable-component-update", "--disable-sync",
                "--window-size=1400,1000", f"--user-data-dir={profile}"):
        options.add_argument(arg)
    options.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    driver = webdriver.Chrome(service=Service(shutil.which("chromedriver")), options=options)
    driver.set_script_timeout(600)
    driver.set_page_load_timeout(600)
    return driver


def codebook_for(name: str, directory: Path, solve: bool) -> Path | None:
    path = directory / f"{name}.h5"
    if path.exists():
        return path
    if not solve:
        return None
    import pgdcli

    start = time.perf_counter()
    result = pgdcli.solve(pgdcli.load_spec(ROOT / "problems" / f"{name}.yaml"))
    result.codebook.save(path)
    print(f"solved {name} ({time.perf_counter() - start:.0f} s)", file=sys.stderr)
    return path


def python_curves(cb, axis: str, point: dict) -> tuple[float, float]:
    """The same 400-sample curves of every unknown by Codebook.evaluate_series (the library's path for a
    trajectory: the other coordinates contracted once): (least, median) seconds over 40 blocks of 10 calls."""
    samples = np.linspace(*cb.coordinate(axis).domain, 400)
    blocks = []
    cb.evaluate_series(point, {axis: samples})
    for _ in range(40):
        start = time.perf_counter()
        for _ in range(10):
            cb.evaluate_series(point, {axis: samples})
        blocks.append((time.perf_counter() - start) / 10)
    return min(blocks), float(np.median(blocks))


def _ms(value: float) -> str:
    """Milliseconds to 0.01 (the browser's clock, over 10 recomputations, resolves no finer)."""
    return f"{value:.2f}" if value >= 0.01 else "< 0.01"


def measure(driver, name: str, path: Path, pages: Path) -> tuple:
    from pgdcli.codebook.codebook import Codebook
    from pgdcli.view import ViewError, write_page
    from selenium.webdriver.support.ui import WebDriverWait

    cb = Codebook.load(path)
    page = pages / f"{name}.html"
    note = ""
    try:
        write_page(cb, page, source=path.name)
    except ViewError:
        write_page(cb, page, source=path.name, force=True)
        note = "over the page limit: written with --force"
    size = page.stat().st_size / 2**20
    driver.get_log("browser")
    start = time.perf_counter()
    driver.get(page.resolve().as_uri())
    WebDriverWait(driver, 600).until(lambda d: d.execute_script(
        "return !!(window.pgdView && (window.pgdView.ready || window.pgdView.errors.length))"))
    load = time.perf_counter() - start
    bench = driver.execute_script("return window.pgdView.bench(40)")
    axis = driver.execute_script("return window.pgdView.lastCurves.axis")
    point = driver.execute_script("return window.pgdView.point()")
    errors = len(driver.execute_script("return window.pgdView.errors"))
    errors += len([e for e in driver.get_log("browser") if e["level"] in ("SEVERE", "WARNING")])
    py_least, py_median = python_curves(cb, axis, {k: v for k, v in point.items() if k != axis})
    numbers = sum(fm.size for fm in cb.fields.values())
    least, curves = bench["curvesLeast"], bench["curves"]
    return (name, f"{len(cb.coordinates)} / {len(cb.unknown_names)}", f"{numbers:,}", f"{size:.1f} MiB",
            f"{load:.2f} s", str(errors), f"{_ms(least)} / {_ms(curves)} ms",
            f"{FRAME_MS / least:.0f}x" if least >= 0.01 else f"> {FRAME_MS / 0.01:.0f}x",
            f"{bench['update']:.1f} ms", "-" if bench["map"] is None else f"{bench['map']:.1f} ms",
            f"{py_least * 1e3:.2f} / {py_median * 1e3:.2f} ms",
            f"{py_least * 1e3 / least:.1f}x" if least >= 0.01 else f"> {py_least * 1e3 / 0.01:.0f}x", note)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dir", type=Path, default=ROOT / "codebooks", help="where the codebooks are (or go)")
    parser.add_argument("--problems", help="comma list [default: every problems/*.yaml]")
    parser.add_argument("--no-solve", action="store_true", help="skip the problems without a codebook in --dir")
    parser.add_argument("--output", type=Path, help="also write the table to this file")
    args = parser.parse_args()
    names = args.problems.split(",") if args.problems else sorted(p.stem for p in (ROOT / "problems").glob("*.yaml"))
    args.dir.mkdir(parents=True, exist_ok=True)
    rows = []
    with tempfile.TemporaryDirectory() as profile, tempfile.TemporaryDirectory() as pages:
        driver = start_browser(profile)
        try:
            for name in names:
                path = codebook_for(name, args.dir, not args.no_solve)
                if path is None:
                    continue
                rows.append(measure(driver, name, path, Path(pages)))
                print(" | ".join(rows[-1]), file=sys.stderr)
        finally:
            driver.quit()
    header = ("codebook", "coords / unknowns", "numbers", "page", "load", "console errors",
              "curves, 400 samples (least / median)", "frame / curves", "update", "map",
              "Python evaluate_series (least / median)", "Python / page", "note")
    report("view_speed.py", markdown_table(rows, header), extra="Chromium (headless)", output=args.output)


if __name__ == "__main__":
    main()
