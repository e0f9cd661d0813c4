#!/usr/bin/env bash
# Lay the vbfe package out as installed, with links, in the folder $1 (replaced): setuptools maps
# top-level folders to vbfe.* (package-dir), which tools that walk the source tree (mypy,
# import-linter's grimp) cannot follow through an editable install.
set -euo pipefail
repo="$(cd "$(dirname "$0")/.." && pwd)"
tree="$1"
rm -rf "$tree"
mkdir -p "$tree/vbfe"
for entry in "$repo"/vbfe/*; do
    ln -s "$entry" "$tree/vbfe/"
done
for package in common drivers acquire calib recon estimate; do
    ln -s "$repo/$package" "$tree/vbfe/$package"
done
