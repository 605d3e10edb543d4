#!/usr/bin/env bash
# tumblebot's one entry point for people and CI.
#
#   ./dev.sh demo   set up .venv (simulation + optimisation extras) and run the main job:
#                   a short design optimisation with the bundled policies, and its report
#   ./dev.sh test   set up .venv (everything, torch pinned) and run lint, types, the import
#                   contracts and all tests (firmware build with avr-gcc, C++ host tests with
#                   ctest, then pytest, the documentation site's build and tutorials among them)
#   ./dev.sh test --fast
#                   the developers' loop (a few minutes): ruff, mypy, lint-imports and the tests marked neither
#                   slow nor hil (nothing runs in simavr); extra arguments go to pytest
#   ./dev.sh setup  set up .venv with everything, run nothing
#
# Works on a fresh Debian/Ubuntu machine with Python 3.11: missing system packages are
# installed with apt-get when running as root (as CI does), otherwise named.
set -euo pipefail
cd "$(dirname "$0")"

VENV=.venv
PYTHON=${PYTHON:-}
if [[ -z "$PYTHON" ]]; then
    for candidate in python3.11 python3; do
        if command -v "$candidate" >/dev/null 2>&1; then PYTHON=$candidate; break; fi
    done
fi
[[ -n "$PYTHON" ]] || { echo "dev.sh: Python 3.11 is required (apt-get install python3.11)" >&2; exit 1; }

apt_install() {
    # apt_install PKG...: install Debian packages that are missing (root only).
    local missing=()
    for pkg in "$@"; do dpkg -s "$pkg" >/dev/null 2>&1 || missing+=("$pkg"); done
    [[ ${#missing[@]} -eq 0 ]] && return 0
    if [[ $(id -u) -eq 0 ]] && command -v apt-get >/dev/null; then
        echo "dev.sh: installing ${missing[*]} with apt-get"
        apt-get update -qq
        DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${missing[@]}" >/dev/null
    else
        echo "dev.sh: please install: sudo apt-get install ${missing[*]}" >&2
        exit 1
    fi
}

ensure_venv() {
    # ensure_venv EXTRAS: create .venv if needed and install tumblebot[EXTRAS] editable.
    if ! "$PYTHON" -c 'import venv, ensurepip' >/dev/null 2>&1; then
        apt_install "python3-venv"
    fi
    if [[ ! -x $VENV/bin/python ]]; then
        echo "dev.sh: creating $VENV with $("$PYTHON" --version)"
        "$PYTHON" -m venv "$VENV"
        "$VENV/bin/python" -m pip install -q --upgrade pip
    fi
    echo "dev.sh: installing tumblebot[$1] into $VENV"
    # strict editable mode: an import-path tree mypy can follow; re-run after adding modules.
    "$VENV/bin/python" -m pip install -q -e ".[$1]" --config-settings editable_mode=strict
}

# Debian packages the firmware build (and `make -C firmware/arduino flash`: avrdude), its host tests
# and the AVR emulator tests need.
FIRMWARE_PACKAGES="gcc-avr avr-libc binutils-avr arduino-core-avr avrdude cmake g++ doctest-dev simavr libsimavr-dev libelf-dev pkg-config"

cmd=${1:-help}
case "$cmd" in
    demo)
        ensure_venv "opt"
        shift
        # A few minutes on 2 cores. Re-running resumes the study (already finished: it
        # just reprints the optimum and rewrites the report).
        mkdir -p runs
        "$VENV/bin/tumblebot" optimize --tasks nav-flat=1 --xi 3 --recipe efficient --trials 40 --batch 48 \
            --storage sqlite:///runs/demo.db --study demo --seed 0 --workers 2 "$@"
        exec "$VENV/bin/tumblebot" report --storage sqlite:///runs/demo.db --study demo -o runs/demo-report \
            --episodes 48 --slice-points 5 --workers 2
        ;;
    setup)
        ensure_venv "train,opt,host,build,dev,agent,docs"
        ;;
    test)
        shift
        if [[ ${1:-} == "--fast" ]]; then
            shift
            apt_install $FIRMWARE_PACKAGES  # the firmware build test runs in the fast loop too
            ensure_venv "train,opt,host,build,dev,agent,docs"
            echo "dev.sh: ruff"
            "$VENV/bin/ruff" check .
            echo "dev.sh: mypy (strict: the package, then tests, hil_tests, benchmarks and reports)"
            "$VENV/bin/mypy"
            "$VENV/bin/mypy" tests hil_tests benchmarks reports
            echo "dev.sh: import contracts (lint-imports: no circles, the arrows between packages)"
            "$VENV/bin/lint-imports"
            echo "dev.sh: pytest (fast: not slow, not hil)"
            exec "$VENV/bin/python" -m pytest -m "not slow and not hil" "$@"
        fi
        apt_install $FIRMWARE_PACKAGES postgresql chromium
        command -v npm >/dev/null 2>&1 || apt_install nodejs npm
        ensure_venv "train,opt,host,build,dev,agent,docs"
        echo "dev.sh: Foxglove Studio for the viewer test (npm ci in docs/screenshot)"
        (cd docs/screenshot && npm ci --no-audit --no-fund --silent)
        echo "dev.sh: firmware build (Debian avr-gcc)"
        make -s -C firmware/arduino
        echo "dev.sh: firmware host tests (CMake/ctest, ASan+UBSan)"
        cmake -S firmware/arduino/test -B build/firmware-tests -DCMAKE_BUILD_TYPE=Debug >/dev/null
        cmake --build build/firmware-tests -j 2 >/dev/null
        ctest --test-dir build/firmware-tests --output-on-failure
        echo "dev.sh: ruff"
        "$VENV/bin/ruff" check .
        echo "dev.sh: mypy (strict: the package, then tests, hil_tests, benchmarks and reports)"
        "$VENV/bin/mypy"
        "$VENV/bin/mypy" tests hil_tests benchmarks reports
        echo "dev.sh: import contracts (lint-imports: no circles, the arrows between packages)"
        "$VENV/bin/lint-imports"
        echo "dev.sh: pytest"
        # pytest exits 5 when it collects nothing; that is a failure here too.
        "$VENV/bin/python" -m pytest --durations=25 "$@"
        ;;
    *)
        sed -n "2,15p" "$0"
        exit 2
        ;;
esac
