#!/usr/bin/env bash
# @spz-loader/core (npm, Apache-2.0, drumath2237/spz-loader: Niantic's SPZ library compiled to
# WebAssembly), the outside reader tests/test_spz.py decodes exported .spz files with: `npm ci` in
# tests/spz_reader, the version pinned by its package-lock.json (integrity-checked), fetched from the
# npm registry once. Without npm or the registry it says why, and that test is skipped with that reason.
# Never fails the build; under CI (LIQUIDGS_REQUIRE_SHARED=1) such a test fails instead of skipping.
set -uo pipefail
reader="$(dirname "$0")/../tests/spz_reader"
if [ -f "$reader/node_modules/@spz-loader/core/package.json" ] &&
    [ "$reader/node_modules/.package-lock.json" -nt "$reader/package-lock.json" ]; then
    exit 0
fi
if ! command -v npm >/dev/null 2>&1; then
    echo "setup_spz_reader: npm is missing (apt-get install npm); the SPZ reader test will be skipped (failed under CI)" >&2
    exit 0
fi
# Bounded: on a closed network npm would otherwise retry for minutes.
if ! npm ci --prefix "$reader" --no-audit --no-fund --loglevel=error --fetch-retries=1 --fetch-timeout=60000; then
    echo "setup_spz_reader: npm ci in $reader failed; the SPZ reader test will be skipped (failed under CI)" >&2
fi
exit 0
