#!/usr/bin/env bash
# Quality per minute, one change at a time: trains lego (or --data) once per variant for the
# same time budget, one after another (never time two at once on a 2-core machine), scores each
# on the first K val views with `nerf eval`, and prints a markdown table. `--iters N` trains each
# for N steps instead: what a step learns, independent of the machine's load (so runs may share
# it), for changes that leave the step's cost alone.
#
#   bash scripts/ablate.sh [--minutes 10 | --iters N] [--views 20] [--data DIR] [--downscale N] [--out DIR] \
#       baseline= planned='lr_schedule = "planned"' random='train_background = "random"'
#
# Each variant is NAME=TOML: keys over the default preset (empty: the preset itself). Runs go to
# <out>/<name>/ (default runs/ablate); a variant whose run exists is scored again, not retrained.
set -euo pipefail
cd "$(dirname "$0")/.."
. scripts/env.sh

minutes=10 iters= views=20 data=../shared/data/nerf_synthetic/lego downscale=1 out=runs/ablate
variants=()
while [ $# -gt 0 ]; do
    case "$1" in
        --minutes) minutes=$2; shift 2 ;;
        --iters) iters=$2; shift 2 ;;
        --views) views=$2; shift 2 ;;
        --data) data=$2; shift 2 ;;
        --downscale) downscale=$2; shift 2 ;;
        --out) out=$2; shift 2 ;;
        -h|--help) sed -n '2,12p' "$0"; exit 0 ;;
        *=*) variants+=("$1"); shift ;;
        *) echo "ablate.sh: '$1' is neither an option nor NAME=TOML" >&2; exit 2 ;;
    esac
done
[ ${#variants[@]} -gt 0 ] || { echo "ablate.sh: give at least one variant NAME=TOML (baseline= for the preset)" >&2; exit 2; }

nerf=$CARGO_TARGET_DIR/release/nerf
cargo build --release -q --bin nerf
mkdir -p "$out"
rows=()
for variant in "${variants[@]}"; do
    name=${variant%%=*}
    toml=${variant#*=}
    run=$out/$name
    if [ ! -f "$run/curve.csv" ]; then
        printf '%s\n' "$toml" > "$out/$name.toml"
        if [ -n "$iters" ]; then length=(--iters "$iters"); else length=(--time-budget-min "$minutes"); fi
        echo "== $name: training ${length[*]} ($toml)" >&2
        "$nerf" train --data "$data" --downscale "$downscale" --config "$out/$name.toml" \
            "${length[@]}" --out "$run" >&2
    fi
    "$nerf" eval --run "$run" --data "$data" --downscale "$downscale" --split val --limit "$views" \
        --out "$run/eval-val" >/dev/null
    rows+=("$("$NERF_PYTHON" - "$run" "$name" "$toml" <<'EOF'
import csv, json, sys
run, name, toml = sys.argv[1:]
rows = list(csv.DictReader(open(f"{run}/curve.csv")))
last = rows[-1]
first_val = last["val_psnr"] or "–"
mean = json.load(open(f"{run}/eval-val/metrics.json"))["psnr_mean"]
steps, minutes = int(last["step"]), float(last["minutes"])
change = toml.replace("\n", "; ") or "(preset)"
print(f"| {name} | `{change}` | {steps:,} | {steps / minutes:,.0f} | {first_val} | **{mean:.2f}** |")
EOF
)")
done
echo
echo "| variant | change | steps | steps/min | val view 0 | mean of $views val views |"
echo "|---|---|---|---|---|---|"
printf '%s\n' "${rows[@]}"
