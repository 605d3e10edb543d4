"""The documentation site: it builds strictly, its tutorials run as written, it draws in a
browser, and it speaks of the repository alone."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from tests.helpers import load_script

ROOT = Path(__file__).resolve().parents[2]
DOCS = ROOT / "docs"
VENV_BIN = Path(sys.executable).parent
RUNNABLE = ("bash", "python")
NEEDS = re.compile(r"^<!--\s*needs:\s*(.+?)\s*-->$")
FENCE = re.compile(r"^```(\w*)\s*$")
#: tutorials and how long each may take (s) on a busy 2-core machine; the slow ones are marked
TUTORIALS = {
    "getting-started.md": (600, ()),
    "tutorials/build.md": (600, ()),
    "tutorials/design.md": (1200, ("slow",)),
    "tutorials/train.md": (1200, ("slow",)),
    "tutorials/scale-out.md": (1200, ("slow",)),
    "tutorials/trials.md": (1200, ("slow", "hil")),
    "tutorials/calibrate.md": (2400, ("slow", "hil")),
}


def blocks(page: Path) -> list[tuple[str, str]]:
    """The page's runnable fenced blocks, ``(language, code)``, in order, without the ones
    whose preceding line marks them ``<!-- needs: … -->`` (the robot, say)."""
    out: list[tuple[str, str]] = []
    lines = page.read_text().splitlines()
    i, previous = 0, ""
    while i < len(lines):
        opened = FENCE.match(lines[i].strip()) if lines[i].lstrip().startswith("```") else None
        if opened is None:
            if lines[i].strip():
                previous = lines[i].strip()
            i += 1
            continue
        language, body = opened.group(1), []
        i += 1
        while i < len(lines) and lines[i].strip() != "```":
            body.append(lines[i])
            i += 1
        i += 1
        if language in RUNNABLE and not NEEDS.match(previous):
            out.append((language, "\n".join(body) + "\n"))
        previous = "```"
    return out


def script_of(page: Path, work: Path) -> str:
    """One bash script that runs the page's blocks in order, in ``work``, stopping at the first failure."""
    parts = ["set -euo pipefail", f"cd {work}"]
    for n, (language, code) in enumerate(blocks(page)):
        if language == "python":
            (work / f".block-{n}.py").write_text(code)
            parts.append(f"python .block-{n}.py")
        else:
            parts.append(code)
    return "\n".join(parts) + "\n"


def workspace(tmp_path: Path) -> Path:
    """A folder that looks like the repository's root (its files linked in), with a fresh ``runs/``."""
    work = tmp_path / "repo"
    work.mkdir()
    for entry in ROOT.iterdir():
        if entry.name not in ("runs", ".git", ".venv", "site"):
            (work / entry.name).symlink_to(entry)
    (work / "runs").mkdir()
    return work


def test_that_the_tutorial_runner_finds_blocks_and_skips_the_ones_marked_as_needing_hardware(tmp_path: Path) -> None:
    page = tmp_path / "page.md"
    page.write_text("intro\n\n```bash\necho one\n```\n\n<!-- needs: the robot -->\n```bash\nflash\n```\n\n"
                    "```text\nnot run\n```\n\n```python\nprint(2)\n```\n")
    assert blocks(page) == [("bash", "echo one\n"), ("python", "print(2)\n")]
    assert "flash" not in script_of(page, tmp_path)


def test_that_every_tutorial_is_listed_here() -> None:
    pages = {str(p.relative_to(DOCS)) for p in (DOCS / "tutorials").glob("*.md")} | {"getting-started.md"}
    assert pages == set(TUTORIALS)
    assert all(blocks(DOCS / page) for page in TUTORIALS)


@pytest.mark.parametrize("page", [pytest.param(p, marks=[getattr(pytest.mark, m) for m in marks], id=p)
                                  for p, (_, marks) in TUTORIALS.items()])
def test_that_the_tutorial_runs_as_written(page: str, tmp_path: Path) -> None:
    work = workspace(tmp_path)
    env = {**os.environ, "PATH": f"{VENV_BIN}:{os.environ['PATH']}", "PYTHONUNBUFFERED": "1"}
    run = subprocess.run(["bash", "-c", script_of(DOCS / page, work)], cwd=work, env=env, capture_output=True,
                         text=True, timeout=TUTORIALS[page][0], stdin=subprocess.DEVNULL, check=False)
    assert run.returncode == 0, f"{page} failed (exit {run.returncode}):\n{run.stdout[-4000:]}\n{run.stderr[-4000:]}"
    assert "Traceback" not in run.stderr, run.stderr[-4000:]


@pytest.fixture(scope="module")
def site(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("site")
    build = subprocess.run([str(VENV_BIN / "mkdocs"), "build", "--strict", "--site-dir", str(out)], cwd=ROOT,
                           capture_output=True, text=True, timeout=600, check=False,
                           env={**os.environ, "NO_MKDOCS_2_WARNING": "1"})
    assert build.returncode == 0, build.stderr[-6000:]
    return out


def test_that_the_site_builds_strictly_with_every_page_and_the_generated_command_reference(site: Path) -> None:
    assert (site / "index.html").is_file() and (site / "tutorials" / "design" / "index.html").is_file()
    reference = (site / "reference" / "cli" / "index.html").read_text()
    for command in ("tumblebot optimize", "tumblebot trial run", "tumblebot twin check", "tumblebot calibrate",
                    "tumblebot build", "tumblebot bench excite", "--slice-points"):
        assert command in reference, command
    assert "tumblebot.sim.world.design" in (site / "reference" / "api" / "index.html").read_text()
    assert (site / "_repo" / "reports" / "thesis-reproduction" / "slices.png").is_file()


def test_that_the_command_reference_is_what_help_prints() -> None:
    module = load_script(DOCS / "_hooks" / "site.py", "tumblebot_docs_hooks")
    reference = module.cli_reference()
    help_text = subprocess.run([str(VENV_BIN / "tumblebot"), "optimize", "--help"], capture_output=True, text=True,
                               env={**os.environ, "COLUMNS": module.HELP_COLUMNS}, check=True).stdout
    assert help_text.strip() in reference


def test_that_the_readme_fits_one_screen_and_opens_with_the_two_commands() -> None:
    lines = (ROOT / "README.md").read_text().splitlines()
    assert len(lines) <= 150
    assert lines[2] == "```bash" and lines[3].startswith("./dev.sh demo") and lines[4].startswith("./dev.sh test")


def _documents() -> list[Path]:
    found = [ROOT / "README.md", *DOCS.rglob("*.md"), *(ROOT / "reports").rglob("*.md"),
             *(ROOT / "benchmarks").rglob("*.md")]
    return [p for p in found if "node_modules" not in p.parts]


def test_that_no_document_cites_a_spec_or_an_issue() -> None:
    cited = re.compile(r"\bSPEC\b|(?i:\bissues?\b)")
    offenders = [f"{p.relative_to(ROOT)}:{n}: {line.strip()[:100]}" for p in _documents()
                 for n, line in enumerate(p.read_text().splitlines(), 1) if cited.search(line)]
    assert offenders == []


@pytest.mark.slow
def test_that_the_site_draws_in_headless_chromium(site: Path, tmp_path: Path) -> None:
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    if chromium is None:
        if os.environ.get("CI"):
            pytest.fail("Chromium is not installed; ./dev.sh test installs it")
        pytest.skip("Chromium is not installed (apt-get install chromium)")
    import http.server
    import threading
    from functools import partial

    import numpy as np
    from PIL import Image

    handler = partial(http.server.SimpleHTTPRequestHandler, directory=str(site))
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    try:
        for page, words in (("", ("tumblebot", "Tutorials")), ("tutorials/design/", ("Optimise", "Slices"))):
            url = f"http://127.0.0.1:{server.server_address[1]}/{page}"
            shot = tmp_path / f"{page.replace('/', '_') or 'index'}.png"
            common = [chromium, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars",
                      "--window-size=1280,900", f"--user-data-dir={tmp_path / 'profile'}"]
            dom = subprocess.run([*common, "--dump-dom", url], capture_output=True, text=True, timeout=180,
                                 check=False)
            assert dom.returncode == 0, dom.stderr[-2000:]
            assert all(w in dom.stdout for w in words), dom.stdout[:2000]
            assert "md-nav" in dom.stdout  # Material's navigation was rendered
            subprocess.run([*common, f"--screenshot={shot}", url], capture_output=True, timeout=180, check=False)
            pixels = np.asarray(Image.open(shot).convert("RGB"), dtype=float)
            assert pixels.std() > 20  # text, pictures and a header, not a blank page
            indigo = np.abs(pixels - np.array([63, 81, 181])).sum(axis=2) < 40
            assert indigo.mean() > 0.01  # the theme's header bar: the stylesheet loaded
    finally:
        server.shutdown()
