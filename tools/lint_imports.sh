#!/usr/bin/env bash
# import-linter's contracts ([tool.importlinter] in pyproject.toml) over the vbfe package as
# installed (tools/installed_layout.sh), laid out in .importlinter/ (ignored by git).
set -euo pipefail
repo="$(cd "$(dirname "$0")/.." && pwd)"
tree="$repo/.importlinter"
bash "$repo/tools/installed_layout.sh" "$tree/src"
cd "$tree"
PYTHONPATH="$tree/src" exec lint-imports --config "$repo/pyproject.toml" --no-cache "$@"
