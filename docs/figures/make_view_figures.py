"""Regenerate the pictures of docs/view.md and docs/sensitivity.md.

    python docs/figures/make_view_figures.py

Solves the shipped problems it needs into a temporary directory (drag, heat1d, pendulum: under a
minute), writes their ``pgd view`` pages and photographs them in Debian's headless Chromium
(Selenium: ``pip install -e '.[test]'``, ``apt-get install chromium chromium-driver``):
docs/figures/view.png (the projectile with drag, its sliders moved) and view-field.png (the heat
equation's field over space and time). Then draws, with the code of ``pgd plot``,
docs/figures/sensitivity.png (the pendulum's Sobol indices over time) and phase.png (the
projectile's paths against the reference). The equivalent commands are printed as it goes.
"""

from __future__ import annotations

import shutil
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
DPI = 100
# page -> (problem, {coordinate: value} typed into the number boxes, window size)
PAGES = {
    "view": ("drag", {"k": 0.04, "a": 1.1, "t": 1.25}, (1400, 1060)),
    "view-field": ("heat1d", {"kappa": 0.3, "t": 0.12, "x": 0.3}, (1400, 1000)),
}


def solve_into(problem: str, directory: Path) -> Path:
    from pgdcli import load_spec, solve

    started = time.perf_counter()
    result = solve(load_spec(ROOT / "problems" / f"{problem}.yaml"))
    if not result.converged:
        raise SystemExit(f"error: {problem}: {result.message}")
    print(f"pgd solve problems/{problem}.yaml  ({time.perf_counter() - started:.1f} s)", file=sys.stderr)
    return result.codebook.save(directory / f"{problem}.h5")


def browser(profile: str, size: tuple[int, int]):
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    options = webdriver.ChromeOptions()
    options.binary_location = shutil.which("chromium") or shutil.which("chromium-browser")
    for arg in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage", "--disable-quic",
                "--no-first-run", "--disable-background-networking", "--disable-component-update", "--disable-sync",
                "--hide-scrollbars", f"--window-size={size[0]},{size[1]}", f"--user-data-dir={profile}"):
        options.add_argument(arg)
    return webdriver.Chrome(service=Service(shutil.which("chromedriver")), options=options)


def photograph(codebook: Path, values: dict, size: tuple[int, int], target: Path) -> None:
    from selenium.webdriver.common.by import By
    from selenium.webdriver.common.keys import Keys
    from selenium.webdriver.support.ui import WebDriverWait

    from pgdcli.codebook.codebook import Codebook
    from pgdcli.view import write_page

    cb = Codebook.load(codebook)
    page = write_page(cb, codebook.with_suffix(".html"), source=codebook.name)
    print(f"pgd view codebooks/{codebook.name} -o {page.name}", file=sys.stderr)
    with tempfile.TemporaryDirectory() as profile:
        driver = browser(profile, size)
        try:
            driver.get(page.resolve().as_uri())
            WebDriverWait(driver, 60).until(lambda d: d.execute_script("return window.pgdView && window.pgdView.ready"))
            for name, value in values.items():
                box = driver.find_element(By.ID, f"coord-{cb.coordinate_names.index(name)}-number")
                box.clear()
                box.send_keys(repr(float(value)), Keys.TAB)
            driver.execute_script("return new Promise(r => setTimeout(r, 500))")
            errors = driver.execute_script("return window.pgdView.errors")
            if errors:
                raise SystemExit(f"error: the page of {codebook.name} reported {errors}")
            driver.save_screenshot(str(target))
        finally:
            driver.quit()
    print(f"  -> {target.relative_to(ROOT)}", file=sys.stderr)


def main() -> int:
    from pgdcli.plot.files import render

    with tempfile.TemporaryDirectory(prefix="pgd-view-figures-") as tmp:
        directory = Path(tmp)
        codebooks = {p: solve_into(p, directory) for p in ("drag", "heat1d", "pendulum")}
        for name, (problem, values, size) in PAGES.items():
            photograph(codebooks[problem], values, size, HERE / f"{name}.png")
        print(f"pgd plot codebooks/pendulum.h5 --kind sensitivity --field th --dpi {DPI} -o "
              f"docs/figures/sensitivity.png", file=sys.stderr)
        render(codebooks["pendulum"], "sensitivity", HERE / "sensitivity.png", field="th", dpi=DPI)
        print(f"pgd plot codebooks/drag.h5 --kind phase --x x --y y --at a=0.4 --at a=0.8 --at a=1.2 "
              f"--reference --dpi {DPI} -o docs/figures/phase.png", file=sys.stderr)
        render(codebooks["drag"], "phase", HERE / "phase.png", x="x", y="y", at=["a=0.4", "a=0.8", "a=1.2"],
               reference=True, dpi=DPI)
    return 0


if __name__ == "__main__":
    sys.exit(main())
