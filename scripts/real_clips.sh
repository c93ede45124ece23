#!/usr/bin/env bash
# The real-clip benchmark, rebuilt from public sources (docs/results/real-clips.md):
#   scripts/real_clips.sh DIR
# 1. `liquidgs data download real-clips DIR/clips`: the 8 clips, each checked against its recorded
#    size and SHA-256, with DIR/clips/clips.json naming each source and licence (CC BY-NC and
#    CC BY-NC-SA: keep them out of any repository);
# 2. `liquidgs data video` on each clip, as the benchmark registered them: 40 frames, longest side
#    640, one COLMAP thread (a clip COLMAP refuses is reported and left out: the spec's runs of it
#    then fail alone);
# 3. `liquidgs experiment run docs/experiments/real-clips.yml`: static, MLP, CfC and HexPlane with the
#    quick look's settings on every clip, scored with the test cameras as given and aligned;
# 4. its report. Steps already done (a folder that exists) are skipped, so a stopped rebuild resumes.
# LIQUIDGS (default: liquidgs) is the command to run, e.g. "python -m liquidgs.cli".
set -euo pipefail

if [ $# -ne 1 ]; then
    echo "usage: scripts/real_clips.sh DIR" >&2
    exit 2
fi
out=$1
spec="$(cd "$(dirname "$0")/.." && pwd)/docs/experiments/real-clips.yml"
read -r -a liquidgs <<< "${LIQUIDGS:-liquidgs}"
mkdir -p "$out"

[ -d "$out/clips" ] || "${liquidgs[@]}" data download real-clips "$out/clips"

mkdir -p "$out/scenes" "$out/logs"
for video in "$out"/clips/*.mp4; do
    clip=$(basename "$video" .mp4)
    [ -d "$out/scenes/$clip" ] && continue
    if "${liquidgs[@]}" data video "$video" --out "$out/scenes/$clip" --max-size 640 --frames 40 --threads 1 \
        > "$out/logs/video-$clip.log" 2>&1; then
        echo "$clip: $(grep '^done:' "$out/logs/video-$clip.log")"
    else
        echo "$clip: data video refused it: $(tail -n 1 "$out/logs/video-$clip.log")" >&2
    fi
done

"${liquidgs[@]}" experiment run "$spec" --data-root "$out/scenes" --out "$out/experiment"
"${liquidgs[@]}" experiment report "$out/experiment"
