#!/usr/bin/env bash
# The outside players and readers the tests hold exported files to, each pinned by the
# package-lock.json of its folder (integrity-checked) and fetched from the npm registry once by
# `npm ci` there: tests/splatv_player (gsplat.js, npm `gsplat`, MIT: tests/test_bake_web.py plays
# .splatv files with it) and tests/spz_reader (@spz-loader/core, Apache-2.0, Niantic's SPZ library
# as WebAssembly: tests/test_spz.py decodes .spz files with it). Without npm or the registry it
# says why, and those tests are skipped with that reason.
# Never fails the build; under CI (LIQUIDGS_REQUIRE_SHARED=1) such a test fails instead of skipping.
set -uo pipefail
tests="$(dirname "$0")/../tests"
for folder in splatv_player spz_reader; do
    dir="$tests/$folder"
    if [ -d "$dir/node_modules" ] && [ "$dir/node_modules/.package-lock.json" -nt "$dir/package-lock.json" ]; then
        continue
    fi
    if ! command -v npm >/dev/null 2>&1; then
        echo "setup_npm_tests: npm is missing (apt-get install npm); the tests that use tests/$folder will be skipped (failed under CI)" >&2
        continue
    fi
    # Bounded: on a closed network npm would otherwise retry for minutes.
    if ! npm ci --prefix "$dir" --no-audit --no-fund --loglevel=error --fetch-retries=1 --fetch-timeout=60000; then
        echo "setup_npm_tests: npm ci in $dir failed; the tests that use tests/$folder will be skipped (failed under CI)" >&2
    fi
done
exit 0
