"""The firmware builds with Debian's toolchain, fits the Uno, and platformio.ini agrees
with the Makefile (same sources, same project flags)."""

from __future__ import annotations

import configparser
import shlex
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
FIRMWARE = ROOT / "firmware" / "arduino"


def make_var(name: str) -> str:
    out = subprocess.run(["make", "-s", "-C", str(FIRMWARE), f"print-{name}"], capture_output=True, text=True,
                         check=True)
    return out.stdout.strip()


def test_that_make_builds_an_elf_that_fits_the_uno() -> None:
    subprocess.run(["make", "-s", "-C", str(FIRMWARE), "all"], check=True, capture_output=True)
    elf = FIRMWARE / "build" / "tumblebot.elf"
    assert elf.is_file()
    sizes = subprocess.run(["avr-size", "-A", str(elf)], capture_output=True, text=True, check=True).stdout
    table = {line.split()[0]: int(line.split()[1]) for line in sizes.splitlines() if line.startswith(".")}
    flash = table[".text"] + table.get(".data", 0)
    ram = table.get(".data", 0) + table.get(".bss", 0)
    assert flash < 32 * 1024 - 512  # the Uno's flash minus the Optiboot bootloader
    assert ram < 2048 - 512  # leave room for the stack


def test_that_platformio_builds_the_same_sources_with_the_same_flags() -> None:
    ini = configparser.ConfigParser()
    ini.read(ROOT / "platformio.ini")
    assert (ROOT / ini["platformio"]["src_dir"]).resolve() == (FIRMWARE / make_var("SRC_DIR")).resolve()
    lib_dir = (ROOT / ini["platformio"]["lib_dir"]).resolve()
    assert (FIRMWARE / make_var("LIB_DIR")).resolve().parent == lib_dir
    env = ini["env:uno"]
    assert env["board"] == "uno" and env["framework"] == "arduino"
    assert shlex.split(env["build_flags"]) == shlex.split(make_var("PROJECT_FLAGS"))
    assert "-mmcu=atmega328p" in make_var("BOARD_FLAGS") and "-DF_CPU=16000000L" in make_var("BOARD_FLAGS")
