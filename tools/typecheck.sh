#!/usr/bin/env bash
# mypy over the vbfe package (settings: [tool.mypy] in pyproject.toml).
# setuptools maps top-level folders to vbfe.* (package-dir), which mypy cannot follow through
# an editable install; so the package is laid out as installed, with links, in .typecheck/
# (ignored by git; a fixed place so that mypy's cache serves the next run), and checked there.
# Extra arguments go to mypy.
set -euo pipefail
repo="$(cd "$(dirname "$0")/.." && pwd)"
tree="$repo/.typecheck"
rm -rf "$tree"
mkdir -p "$tree/vbfe"
for entry in "$repo"/vbfe/*; do
    ln -s "$entry" "$tree/vbfe/"
done
for package in common drivers acquire calib recon estimate; do
    ln -s "$repo/$package" "$tree/vbfe/$package"
done
cd "$tree"
exec python -m mypy --config-file "$repo/pyproject.toml" --cache-dir "$tree/.mypy_cache" \
    -p vbfe "$@"
