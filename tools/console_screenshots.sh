#!/usr/bin/env bash
# The console's tabs after the whole day walked through the window (tests/app/test_console_day.py),
# as PNGs in docs/console/ (offscreen Qt; about 2 minutes on a loaded 2-core machine).
set -euo pipefail
cd "$(dirname "$0")/.."
QT_QPA_PLATFORM=offscreen VBFE_CONSOLE_SHOTS=docs/console \
    python -m pytest -q -n 0 -m slow -p no:cacheprovider tests/app/test_console_day.py
