#!/usr/bin/env bash
# Paths stage (docs/testing.md): every file that docs/*.md, README.md and
# the code's comments name exists (.ci/paths.py), and every intra-doc link
# of the library resolves (rustdoc), so that neither drifts after a move.
set -euo pipefail
cd "$(dirname "$0")/.."
python3 .ci/paths.py
RUSTDOCFLAGS="-D rustdoc::broken_intra_doc_links -A rustdoc::private_intra_doc_links" \
  cargo doc --lib --no-deps --quiet
