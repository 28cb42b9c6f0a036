#!/usr/bin/env bash
# Tracking figures over many filter seeds: one track per seed, scored with `pftrack eval`,
# then the mean and its standard error. A single seed tells little: on the real footage one
# seed's success AUC moves by 0.5 or more when anything in the tracker changes, so compare
# variants by their means over 16 seeds or more, and only by more than two standard errors.
#
#   scripts/eval_seeds.sh real  [options] [-- TRACK_ARGS...]   girl and car4, success AUC
#       and lost frames (how many of them on the target), the confidence's AUROC telling
#       frames on the target from those off it; on a copy whose truth marks the target
#       absent (a box of no size: examples/perturb.rs vanish), the share of those frames
#       the track flags lost
#   scripts/eval_seeds.sh synth [options] [-- TRACK_ARGS...]   synthetic scenarios, angle RMSE
#   scripts/eval_seeds.sh tre   [options] [-- TRACK_ARGS...]   girl and car4 started at
#       --segments K frames spread over each (OTB's temporal robustness evaluation: segment i
#       starts at frame floor(i N / K), or the first frame after it that shows the target,
#       and runs to the end, scored from its start with `eval --segment`); success AUC over
#       the segments' frames pooled
#
# Options:
#   --bin PATH         the pftrack binary (default: target/release/pftrack)
#   --seeds "A B ..."  seeds, or a range A-B (real: filter seeds, default 0-15;
#                      synth: scenario seeds, default 0-11; tre: filter seeds, default 0-3)
#   --segments K       tre only: start frames per sequence (default 20, as OTB)
#   --filter-seed K    synth only: the filter seed of every run (default 0); "same" uses
#                      each scenario's own seed
#   --scenarios "..."  synth only (default: nod pan roll combo depth car)
#   --size WxH         synth only: the frame size the scenarios are rendered at (default:
#                      synth's, 160x120); their renders go to DIR/synth/NAME-SEED-WxH.
#                      Frames longer than 800 px are tracked shrunk toward 640 px unless
#                      `-- --full-size` is given (track's working size)
#   --sequences "..."  real and tre only (default: girl car4)
#   --data DIR         real footage (default: ../shared/data beside the repository)
#   --jobs N           runs side by side (default 2), each on one rayon thread
#   --out DIR          where tracks, reports and logs go (default: a new temporary folder);
#                      synthetic scenarios are rendered once into DIR/synth and reused
# Everything after `--` goes to `pftrack track` (e.g. `-- --no-fit-prior`). With a settings
# file (`-- --config FILE.json`), which `track` takes in place of `--seed`, each run gets a
# copy of the file with its filter seed written in (python3 merges it; the file's own "seed"
# is replaced).
#
# Exits non-zero, naming the runs, when any track or evaluation failed: a summary over the
# runs that worked would look complete and is not printed.
set -euo pipefail

die() { echo "eval_seeds: $*" >&2; exit 2; }

[ $# -ge 1 ] || die "usage: eval_seeds.sh real|synth|tre [options] [-- TRACK_ARGS...]"
mode=$1; shift
case $mode in real|synth|tre) ;; *) die "unknown mode '$mode' (real, synth or tre)";; esac

root=$(cd "$(dirname "$0")/.." && pwd)
bin=$root/target/release/pftrack
seeds=""
filter_seed=0
scenarios="nod pan roll combo depth car"
sequences="girl car4"
data=$root/../shared/data
jobs=2
size=""
segments=20
out=""
track_args=()
while [ $# -gt 0 ]; do
    case $1 in
        --bin) bin=${2:?--bin needs a path}; shift 2;;
        --seeds) seeds=${2:?--seeds needs a list}; shift 2;;
        --filter-seed) filter_seed=${2:?--filter-seed needs a value}; shift 2;;
        --scenarios) scenarios=${2:?--scenarios needs a list}; shift 2;;
        --sequences) sequences=${2:?--sequences needs a list}; shift 2;;
        --size) size=${2:?--size needs WxH}; shift 2;;
        --data) data=${2:?--data needs a folder}; shift 2;;
        --jobs) jobs=${2:?--jobs needs a number}; shift 2;;
        --segments) segments=${2:?--segments needs a number}; shift 2;;
        --out) out=${2:?--out needs a folder}; shift 2;;
        --) shift; track_args=("$@"); break;;
        *) die "unknown option '$1'";;
    esac
done
[ -x "$bin" ] || die "no pftrack binary at $bin (cargo build --release, or --bin PATH)"
[[ $jobs =~ ^[1-9][0-9]*$ ]] || die "--jobs must be a positive whole number, got '$jobs'"
[[ $segments =~ ^[1-9][0-9]*$ ]] || die "--segments must be a positive whole number, got '$segments'"
[[ $filter_seed =~ ^([0-9]+|same)$ ]] || die "--filter-seed must be a number or 'same'"
if [ -n "$size" ]; then
    [ "$mode" = synth ] || die "--size is for synth (the real footage has its own size)"
    [[ $size =~ ^[0-9]+x[0-9]+$ ]] || die "--size must be WIDTHxHEIGHT, got '$size'"
fi
if [ -z "$seeds" ]; then
    case $mode in real) seeds=0-15;; synth) seeds=0-11;; tre) seeds=0-3;; esac
fi
if [[ $seeds =~ ^([0-9]+)-([0-9]+)$ ]]; then
    seeds=$(seq -s ' ' "${BASH_REMATCH[1]}" "${BASH_REMATCH[2]}")
fi
for s in $seeds; do [[ $s =~ ^[0-9]+$ ]] || die "bad seed '$s'"; done
[ -n "${seeds// /}" ] || die "no seeds"
# A seed given twice would run twice into the same files and count twice in the means,
# shrinking their standard errors.
repeated=$(tr ' ' '\n' <<<"$seeds" | grep . | sort -n | uniq -d | tr '\n' ' ')
[ -z "$repeated" ] || die "seeds given more than once: $repeated"
out=${out:-$(mktemp -d /tmp/pftrack-seeds.XXXXXX)}
mkdir -p "$out"
if [ "$mode" != synth ]; then
    for q in $sequences; do
        [ -f "$data/$q/groundtruth_rect.txt" ] || die "no ground truth at $data/$q (--data DIR)"
    done
fi

# One line per run, "NAME SEED SEGMENT" (the segment only with tre), run by $jobs workers;
# each run writes NAME-SEED[-SEGMENT].json and .log, or .failed.
run_one() {
    local name=$1 seed=$2 seg=${3:-} base=$out/$1-$2${3:+-$3} input init fseed start
    local scored=(--json)
    rm -f "$base.failed"
    if [ "$mode" != synth ]; then
        input=$data/$name/img
        truth=$data/$name/groundtruth_rect.txt
        init=(--init-truth "$truth")
        fseed=$seed
        if [ -n "$seg" ]; then
            # The segment's start, moved on to the first frame whose box has a size (OTB
            # marks a frame without the target by a box of no size).
            start=$(awk -F'[,\t ]+' -v s="$(( seg * $(grep -c . "$truth") / segments ))" \
                'NR - 1 >= s && $3 > 0 && $4 > 0 { print NR - 1; exit }' "$truth")
            [ -n "$start" ] || { echo "no frame with the target from segment $seg on" >"$base.log"; touch "$base.failed"; return 0; }
            init+=(--start-frame "$start")
            scored+=(--segment)
        fi
    else
        local sdir=$out/synth/$name-$seed${size:+-$size}
        if [ ! -f "$sdir/truth.csv" ]; then
            "$bin" synth "$sdir" --scenario "$name" --seed "$seed" ${size:+--size "$size"} \
                >"$base.log" 2>&1 ||
                { touch "$base.failed"; return 0; }
        fi
        input=$sdir/frames
        init=(--init-file "$sdir/init.txt")
        truth=$sdir/truth.csv
        if [ "$filter_seed" = same ]; then fseed=$seed; else fseed=$filter_seed; fi
    fi
    # The seed as a flag, or written into a copy of the settings file given.
    local args=() seeded=(--seed "$fseed") i a
    for ((i = 0; i < ${#track_args[@]}; i++)); do
        a=${track_args[i]}
        if [ "$a" = --config ] || [[ $a == --config=* ]]; then
            local file=${a#--config=}
            if [ "$a" = --config ]; then i=$((i + 1)); file=${track_args[i]:-}; fi
            python3 - "$file" "$fseed" "$base.config.json" <<'PY' >>"$base.log" 2>&1 ||
import json, sys
with open(sys.argv[1]) as f:
    settings = json.load(f)
if not isinstance(settings, dict):
    sys.exit(f"{sys.argv[1]}: the settings are not a JSON object")
settings["seed"] = int(sys.argv[2])
with open(sys.argv[3], "w") as f:
    json.dump(settings, f)
PY
                { touch "$base.failed"; return 0; }
            args+=(--config "$base.config.json")
            seeded=()
        else
            args+=("$a")
        fi
    done
    if RAYON_NUM_THREADS=1 "$bin" track "$input" "${init[@]}" --backend cpu "${seeded[@]}" \
        "${args[@]}" --out "$base.csv" >>"$base.log" 2>&1 &&
        "$bin" eval "$truth" "$base.csv" "${scored[@]}" >"$base.json" 2>>"$base.log"; then
        :
    else
        touch "$base.failed"
    fi
}
export -f run_one
export mode bin out data filter_seed segments size
names=$sequences
[ "$mode" = synth ] && names=$scenarios
# The runs' names: NAME-SEED, or NAME-SEED-SEGMENT with tre.
parts=("")
[ "$mode" = tre ] && read -r -a parts <<<"$(seq -s ' ' 0 $((segments - 1)))"
for n in $names; do for s in $seeds; do for g in "${parts[@]}"; do echo "$n $s${g:+ $g}"; done; done; done |
    xargs -P "$jobs" -L 1 bash -c "$(declare -p track_args); run_one \"\$0\" \"\$1\" \"\${2:-}\""
runs() { for g in "${parts[@]}"; do echo "$1-$2${g:+-$g}"; done; }

# Only this invocation's runs: a reused --out may hold marks of other seeds or scenarios.
failed=""
for n in $names; do for s in $seeds; do for r in $(runs "$n" "$s"); do
    [ ! -e "$out/$r.failed" ] || failed+="$r "
done; done; done
if [ -n "$failed" ]; then
    echo "eval_seeds: these runs failed (logs in $out): $failed" >&2
    exit 1
fi

# A number field of a one-line JSON report ("key":value, or within "angle_rmse_deg"); a
# `null` gives nothing rather than an empty value read as 0.
field() { grep -o "\"$2\":[-0-9.eE+][-0-9.eE+]*" "$1" | head -1 | cut -d: -f2 || true; }

# A track shorter than its truth (track arguments such as --max-frames) has its angle and
# centre errors taken over the frames tracked: said, so that no row passes for a whole one.
short=""
for n in $names; do for s in $seeds; do for r in $(runs "$n" "$s"); do
    m=$(field "$out/$r.json" missing)
    [ "${m:-0}" = 0 ] || short+="$r ($m) "
done; done; done
if [ -n "$short" ]; then
    echo "eval_seeds: warning: these runs miss truth frames (how many), and their errors are" \
        "over the frames tracked only: $short" >&2
fi
# One axis of a report's angle gain; empty where the truth hardly turns about it (null).
gain() {
    grep -o '"angle_gain":{[^}]*}' "$1" | grep -o "\"$2\":[-0-9.eE+][-0-9.eE+]*" |
        cut -d: -f2 || true
}
# The mean of the numbers on stdin to 3 places, "-" when there are none.
mean_or_dash() { awk '{ s += $1; n++ } END { if (n) printf "%.3f", s / n; else printf "-" }'; }
# Mean and standard error of the numbers on stdin ("-" for the error of a single number).
stats() { awk '{ s += $1; q += $1 * $1; n++ } END {
    if (n == 0) { printf "- ± -"; exit }
    m = s / n; if (n < 2) { printf "%.3f ± -", m; exit }
    v = (q - n * m * m) / (n - 1); if (v < 0) v = 0;
    printf "%.3f ± %.3f", m, sqrt(v / n) }'; }

echo "pftrack: $bin"
echo "track arguments: ${track_args[*]:-(none)}; runs in $out"
if [ "$mode" = tre ]; then
    echo "success AUC over $segments starts (OTB TRE: the segments' frames pooled; mean ± standard"
    echo "error over filter seeds $seeds), and from the first frame alone (OPE)"
    for q in $sequences; do
        # Pooled: the segments' AUCs weighted by the frames each scored (those showing the
        # target, a frame without an estimate a failure).
        per=""; for s in $seeds; do
            per+="$(for r in $(runs "$q" "$s"); do
                f=$out/$r.json
                echo "$(field "$f" success_auc) $(field "$f" truth_frames) $(field "$f" absent)"
            done | awk '{ s += $1 * ($2 - $3); n += $2 - $3 } END { printf "%.6f", s / n }') "
        done
        m=$(echo "$per" | tr ' ' '\n' | grep . | stats)
        o=$(for s in $seeds; do field "$out/$q-$s-0.json" success_auc; done | stats)
        printf '%-6s TRE AUC %s  OPE AUC %s\n' "$q" "$m" "$o"
        printf '       per seed: %s\n' "$(for v in $per; do printf '%.3f ' "$v"; done)"
    done
elif [ "$mode" = real ]; then
    echo "success AUC (mean ± standard error over filter seeds $seeds)"
    for q in $sequences; do
        per=""; for s in $seeds; do per+="$(field "$out/$q-$s.json" success_auc) "; done
        m=$(echo "$per" | tr ' ' '\n' | grep . | stats)
        c=$(for s in $seeds; do field "$out/$q-$s.json" mean_centre_error_px; done | stats)
        printf '%-6s AUC %s  centre error %s px\n' "$q" "$m" "$c"
        printf '       per seed: %s\n' "$(for v in $per; do printf '%.3f ' "$v"; done)"
        l=$(for s in $seeds; do field "$out/$q-$s.json" lost; done | mean_or_dash)
        printf '       lost frames a seed (the target shown): %s\n' "$l"
        # How far the tracker's own signals can be trusted: the lost flag on and off the
        # target (IoU 0.5), and how well the confidence tells the two apart.
        lo=$(for s in $seeds; do field "$out/$q-$s.json" lost_on_target; done | mean_or_dash)
        off=$(for s in $seeds; do
            f=$out/$q-$s.json
            echo "$(field "$f" evaluated) $(field "$f" on_target)"
        done | awk '{ print $1 - $2 }' | mean_or_dash)
        printf '       of them on the target (IoU >= 0.5): %s; frames off it a seed: %s\n' "$lo" "$off"
        # Seeds whose every frame is on the target have none: the mean is over the others.
        au=$(for s in $seeds; do field "$out/$q-$s.json" score_auroc; done)
        u=$(echo "$au" | { grep . || true; } | stats)
        n=$(echo "$au" | { grep -c . || true; })
        printf '       score AUROC (frames on the target against those off it): %s (%s of %s seeds)\n' \
            "$u" "$n" "$(echo $seeds | wc -w)"
        # Where the truth marks the target absent: how often the track said so.
        a=$(field "$out/$q-$(set -- $seeds; echo "$1").json" absent)
        if [ "${a:-0}" != 0 ]; then
            # A seed whose track has no lost column, or no estimate on those frames, has no
            # share: "-" in its place, left out of the mean.
            per=""; for s in $seeds; do
                f=$out/$q-$s.json
                al=$(field "$f" absent_lost); ae=$(field "$f" absent_estimated)
                if [ -n "$al" ] && [ "${ae:-0}" != 0 ]; then
                    per+="$(awk -v l="$al" -v e="$ae" 'BEGIN { printf "%.3f", l / e }') "
                else
                    per+="- "
                fi
            done
            m=$(echo "$per" | tr ' ' '\n' | { grep -v -e '^-$' -e '^$' || true; } | stats)
            printf '       target absent on %s frames: share flagged lost %s\n' "$a" "$m"
            printf '       per seed: %s\n' "$per"
        fi
    done
else
    echo "angle RMSE in degrees, mean over scenario seeds $seeds (filter seed $filter_seed${size:+, rendered at $size});"
    echo "gain: slope of the estimate against the truth per axis, mean over the seeds where the truth turns"
    echo "turn: RMSE of the whole rotation's error (the angle of R_est R_truth^T), mean over the seeds"
    printf '%-6s %7s %7s %7s %7s %10s %5s %8s %7s %7s %7s\n' scenario rx ry rz turn centre_px lost \
        worst gain_rx gain_ry gain_rz
    total=0
    for sc in $scenarios; do
        row=$(for s in $seeds; do
            f=$out/$sc-$s.json
            echo "$(field "$f" rx) $(field "$f" ry) $(field "$f" rz) $(field "$f" mean_centre_error_px) $(field "$f" rmse) $(field "$f" lost)"
        done | awk -v sc="$sc" '{ x += $1; y += $2; z += $3; c += $4; t += $5; l += $6; n++;
                w = $1 + $2 + $3; if (w > worst) worst = w }
            END { printf "%-6s %7.2f %7.2f %7.2f %7.2f %10.2f %5d %8.1f %.6f\n", sc, x / n, y / n,
                  z / n, t / n, c / n, l, worst, (x + y + z) / n }')
        g=""
        for ax in rx ry rz; do
            g+=" $(for s in $seeds; do gain "$out/$sc-$s.json" "$ax"; done | mean_or_dash)"
        done
        # shellcheck disable=SC2086 # the three gains are separate words
        printf '%s %7s %7s %7s\n' "${row% *}" $g
        total=$(awk -v t="$total" -v r="${row##* }" 'BEGIN { printf "%.6f", t + r }')
    done
    printf 'sum of the per-axis means: %.1f\n' "$total"
fi
