#!/usr/bin/env bash
# Set up and run the main job on the bundled data.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/bootstrap.sh
build_dir=${LIDARSIM_BUILD_DIR:-build}
out=${1:-out/demo}
mkdir -p "$out"
echo "demo: main job not wired yet" >&2
