#!/usr/bin/env bash
# gsplat.js (npm `gsplat`, MIT, huggingface/gsplat.js), the player tests/test_bake_web.py plays
# exported .splatv files with: `npm ci` in tests/splatv_player, the version pinned by its
# package-lock.json (integrity-checked), fetched from the npm registry once. Without npm or the
# registry it says why, and that test is skipped with that reason.
# Never fails the build; under CI (LIQUIDGS_REQUIRE_SHARED=1) such a test fails instead of skipping.
set -uo pipefail
player="$(dirname "$0")/../tests/splatv_player"
if [ -f "$player/node_modules/gsplat/package.json" ] &&
    [ "$player/node_modules/.package-lock.json" -nt "$player/package-lock.json" ]; then
    exit 0
fi
if ! command -v npm >/dev/null 2>&1; then
    echo "setup_splatv_player: npm is missing (apt-get install npm); the gsplat.js splatv test will be skipped (failed under CI)" >&2
    exit 0
fi
# Bounded: on a closed network npm would otherwise retry for minutes.
if ! npm ci --prefix "$player" --no-audit --no-fund --loglevel=error --fetch-retries=1 --fetch-timeout=60000; then
    echo "setup_splatv_player: npm ci in $player failed; the gsplat.js splatv test will be skipped (failed under CI)" >&2
fi
exit 0
