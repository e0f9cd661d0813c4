#!/usr/bin/env bash
# The manual: mkdocs over docs/ (mkdocs.yml), warnings as errors. mkdocstrings reads the
# package as installed (tools/installed_layout.sh) from .docs-src/ (ignored by git).
# Arguments go to mkdocs (default: build into site/).
set -euo pipefail
repo="$(cd "$(dirname "$0")/.." && pwd)"
bash "$repo/tools/installed_layout.sh" "$repo/.docs-src"
cd "$repo"
exec python -m mkdocs "${@:-build}" --strict
