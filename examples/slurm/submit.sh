#!/bin/bash
# Queue a sharded render and its merge:
#   BUNDLE=/shared/lego OUT=/shared/lego-orbit bash submit.sh 8 --orbit --frames 120
# runs render.sbatch as a job array of 8 tasks (shards 0/8 .. 7/8) and merge.sbatch once all of
# them succeeded (afterok). BUNDLE, OUT and NERF_RENDER reach the jobs through --export=ALL.
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
shards="${1:?usage: BUNDLE=... OUT=... bash submit.sh SHARDS [what to render, default --orbit]}"
shift
array="$(sbatch --parsable --export=ALL --array="0-$((shards - 1))" "$here/render.sbatch" "$@")"
array="${array%%;*}"  # --parsable prints "id" or "id;cluster"
merge="$(sbatch --parsable --export=ALL --dependency="afterok:$array" "$here/merge.sbatch")"
echo "render: job array $array ($shards shards); merge: job ${merge%%;*} after it"
