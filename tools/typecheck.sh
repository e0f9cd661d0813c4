#!/usr/bin/env bash
# mypy over the vbfe package (settings: [tool.mypy] in pyproject.toml), checked in the package
# as installed (tools/installed_layout.sh) in .typecheck/ (ignored by git; a fixed place so that
# mypy's cache serves the next run). Extra arguments go to mypy.
set -euo pipefail
repo="$(cd "$(dirname "$0")/.." && pwd)"
tree="$repo/.typecheck"
bash "$repo/tools/installed_layout.sh" "$tree"
cd "$tree"
exec python -m mypy --config-file "$repo/pyproject.toml" --cache-dir "$tree/.mypy_cache" \
    -p vbfe "$@"
