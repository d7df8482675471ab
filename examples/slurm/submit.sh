#!/bin/bash
# Queue a sharded render and its merge:
#   BUNDLE=/shared/lego OUT=/shared/lego-orbit bash submit.sh 8 --orbit --frames 120
# runs render.sbatch as a job array of 8 tasks (shards 0/8 .. 7/8) and merge.sbatch once all of
# them succeeded (afterok). BUNDLE, OUT and NERF_RENDER reach the jobs through --export=ALL.
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
usage="usage: BUNDLE=... OUT=... bash submit.sh SHARDS [what to render, default --orbit]"
shards="${1:?$usage}"
shift
# Refused here rather than by every task once the array has waited in the queue.
case "$shards" in
  '' | *[!0-9]* | 0*) echo "submit.sh: SHARDS must be a whole number from 1, not '$shards'; $usage" >&2; exit 2 ;;
esac
# nerf-render's --shard takes 1 to 10000 shards (the length check first: bash's integers overflow).
if [ "${#shards}" -gt 5 ] || [ "$shards" -gt 10000 ]; then
  echo "submit.sh: SHARDS must be at most 10000 (nerf-render's --shard limit), not $shards" >&2
  exit 2
fi
: "${BUNDLE:?set BUNDLE to the scene bundle (nerf export --out DIR); $usage}"
: "${OUT:?set OUT to an output directory every task can write; $usage}"
command -v sbatch >/dev/null || { echo "submit.sh: sbatch not found: run this where Slurm's commands are" >&2; exit 1; }
array="$(sbatch --parsable --export=ALL --array="0-$((shards - 1))" "$here/render.sbatch" "$@")"
array="${array%%;*}"  # --parsable prints "id" or "id;cluster"
merge="$(sbatch --parsable --export=ALL --dependency="afterok:$array" "$here/merge.sbatch")"
echo "render: job array $array ($shards shards); merge: job ${merge%%;*} after it"
