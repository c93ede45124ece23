#!/usr/bin/env bash
# The real-clip benchmark, rebuilt from public sources (docs/results/real-clips.md):
#   scripts/real_clips.sh DIR
# 1. `liquidgs data download real-clips DIR/clips`: the 8 clips, each checked against its recorded
#    size and SHA-256, with DIR/clips/clips.json naming each source and licence (CC BY-NC and
#    CC BY-NC-SA: keep them out of any repository);
# 2. `liquidgs data video` on each clip, as the benchmark registered them: 80 frames (every frame of a shorter clip), longest side
#    640, one COLMAP thread (a clip COLMAP refuses is reported and left out: the spec's runs of it
#    then fail alone);
# 3. `liquidgs experiment run docs/experiments/real-clips.yml`: static, MLP, CfC and HexPlane with the
#    quick look's settings on every clip, scored with the test cameras as given and aligned (into
#    DIR/experiment); then real-clips-without-regularisers.yml, seed 0 of each field with every motion
#    weight at 0 (into DIR/experiment-without-regularisers); then with the motion evidence (the flow
#    loss and the static/dynamic split: real-clips-motion.yml) and without each piece in turn
#    (real-clips-motion-without-flow.yml, -without-split.yml), and with the tracks
#    (real-clips-motion-with-tracks.yml), into DIR/experiment-<spec>; and the motion evidence as a
#    capture's defaults give it (the flow loss at 0.04, the split, HexPlane without its neighbour terms:
#    real-clips-defaults.yml, into DIR/experiment-defaults), and the same with the quick look's schedule
#    doubled to 3,000 iterations (real-clips-defaults-3000.yml, into DIR/experiment-defaults-3000), and
#    without the evidence at 3,000 (real-clips-3000.yml, into DIR/experiment-3000);
# 4. masks of the moving subject on each test view, from the boxes drawn by eye in
#    docs/experiments/real-clips-boxes.json, and `liquidgs eval --mask` of every finished run of a clip
#    that has them (scores inside and outside, test cameras as given and aligned); the runs with and
#    without the motion evidence once each, also inside the scene's own motion masks (`eval --mask auto`,
#    with the rendered motion's end-point error: RUN/eval-auto.json), so a stopped rebuild does not score
#    them again;
# 5. how the scenes' own motion masks (data flow) agree with the boxes (DIR/mask-agreement.txt);
# 6. the reports, and the specs compared pair by pair with the verdict rule (the evidence against
#    none, each piece off in turn, the tracks, the schedules; each spec's margins over the static model:
#    docs/experiments/real_clips_compare.py, into
#    DIR/comparisons.md). Steps already done (a folder that exists) are skipped, so a stopped rebuild resumes.
# LIQUIDGS (default: liquidgs) is the command to run, e.g. "python -m liquidgs.cli"; PYTHON (default:
# python3) one with liquidgs' dependencies, for the masks.
set -euo pipefail

if [ $# -ne 1 ]; then
    echo "usage: scripts/real_clips.sh DIR" >&2
    exit 2
fi
out=$1
root="$(cd "$(dirname "$0")/.." && pwd)"
specs="$root/docs/experiments"
read -r -a liquidgs <<< "${LIQUIDGS:-liquidgs}"
read -r -a python <<< "${PYTHON:-python3}"
mkdir -p "$out"

[ -d "$out/clips" ] || "${liquidgs[@]}" data download real-clips "$out/clips"

mkdir -p "$out/scenes" "$out/logs"
for video in "$out"/clips/*.mp4; do
    clip=$(basename "$video" .mp4)
    [ -d "$out/scenes/$clip" ] && continue
    if "${liquidgs[@]}" data video "$video" --out "$out/scenes/$clip" --max-size 640 --frames 80 --threads 1 \
        > "$out/logs/video-$clip.log" 2>&1; then
        echo "$clip: $(grep '^done:' "$out/logs/video-$clip.log")"
    else
        echo "$clip: data video refused it: $(tail -n 1 "$out/logs/video-$clip.log")" >&2
    fi
done

"${liquidgs[@]}" experiment run "$specs/real-clips.yml" --data-root "$out/scenes" --out "$out/experiment"
"${liquidgs[@]}" experiment run "$specs/real-clips-without-regularisers.yml" --data-root "$out/scenes" \
    --out "$out/experiment-without-regularisers"
# The specs beside real-clips.yml that are run, scored in both kinds of mask and reported alike.
paired_specs=(defaults defaults-3000 3000 motion motion-with-tracks motion-without-flow motion-without-split)
for spec in "${paired_specs[@]}"; do
    "${liquidgs[@]}" experiment run "$specs/real-clips-$spec.yml" --data-root "$out/scenes" --out "$out/experiment-$spec"
done

"${python[@]}" "$root/docs/experiments/real_clips_masks.py" "$out/masks"
for masks in "$out"/masks/*/; do
    clip=$(basename "$masks")
    for run in "$out"/experiment-without-regularisers/*/"$clip"/*/*/; do
        [ -f "$run/results.json" ] || continue
        log="$out/logs/eval-$clip-$(basename "$(dirname "$run")")-$(basename "$run").log"
        "${liquidgs[@]}" eval --run "${run%/}" --mask "${masks%/}" > "$log" 2>&1 \
            || echo "$clip: eval --mask of ${run%/} failed: $(tail -n 1 "$log")" >&2
    done
done
# The runs with the motion evidence and those without it, once each: scored inside the scene's own
# motion masks, with the rendered motion's end-point error (kept as eval-auto.json), then inside the
# boxes where the clip has them (eval.json, which the reports read).
scored_runs=("$out"/experiment/*/*/*/*/)
for spec in "${paired_specs[@]}"; do
    scored_runs+=("$out/experiment-$spec"/*/*/*/*/)
done
for run in "${scored_runs[@]}"; do
    [ -f "$run/results.json" ] || continue
    rel=${run#"$out"/}
    rel=${rel%/}  # experiment-SPEC/DATASET/CLIP/FIELD/HASH
    IFS=/ read -r _ _ clip _ <<< "$rel"
    log="$out/logs/eval-${rel//\//-}"
    if [ ! -f "$run/eval-auto.json" ]; then
        if "${liquidgs[@]}" eval --run "${run%/}" --mask auto --flow-error > "$log-auto.log" 2>&1; then
            mv "$run/eval_per_view.json" "$run/eval-auto_per_view.json"
            mv "$run/eval.json" "$run/eval-auto.json"
        else
            echo "$clip: eval --mask auto of ${run%/} failed: $(tail -n 1 "$log-auto.log")" >&2
        fi
    fi
    if [ -d "$out/masks/$clip" ] && [ ! -f "$run/eval.json" ]; then
        "${liquidgs[@]}" eval --run "${run%/}" --mask "$out/masks/$clip" > "$log.log" 2>&1 \
            || echo "$clip: eval --mask of ${run%/} failed: $(tail -n 1 "$log.log")" >&2
    fi
done
"${python[@]}" "$root/docs/experiments/real_clips_mask_agreement.py" "$out/scenes" | tee "$out/mask-agreement.txt"
"${liquidgs[@]}" experiment report "$out/experiment"
"${liquidgs[@]}" experiment report "$out/experiment-without-regularisers"
for spec in "${paired_specs[@]}"; do
    "${liquidgs[@]}" experiment report "$out/experiment-$spec"
done
"${python[@]}" "$root/docs/experiments/real_clips_compare.py" "$out" | tee "$out/comparisons.md"
