#!/usr/bin/env bash
# Build the documentation site (mkdocs.yml) into site/: reference pages, findings and the API
# reference generated from the docstrings.  --strict turns every warning (a broken link, a
# docstring griffe cannot parse, a page missing from the nav) into an error.
#   pip install -e ".[docs]" && scripts/build_docs.sh
# docs/config.md is generated: refresh it first with
#   python -m bemlearn.pipeline.config_doc > docs/config.md
set -euo pipefail
cd "$(dirname "$0")/.."
export NO_MKDOCS_2_WARNING=1  # the mkdocs 2 banner: not a warning of this build
exec python -m mkdocs build --strict "$@"
