#!/usr/bin/env bash
# Classification over a range of seeds (rigs drawn from the seed): one markdown row per seed
# with the worst of the three pick seeds per scene, as classified and after the simulated
# review (a pick of the true class in each region `classify` lists to confirm), then how many
# cases miss the 99.5 % goal in each.
# Usage: bash bench/classify_seeds.sh FIRST LAST [eval classify options, e.g. --camera 2304x1728]
# About 10 s a seed at 800x600 and 30 s at 4 MP on a 2-core machine (release build).
set -euo pipefail
first=${1:?first seed}
last=${2:?last seed}
shift 2
cd "$(dirname "$0")/.."
author() { cargo run --release -q --bin restage-author -- "$@"; }
echo "| seed | vase / bowl / jar | after review |"
echo "| --- | --- | --- |"
log=$(mktemp)
trap 'rm -f "$log"' EXIT
all=()
reviewed=()
for ((s = first; s <= last; s++)); do
    if ! out=$(author eval classify --seed "$s" "$@" 2>"$log"); then
        cat "$log" >&2
        exit 1
    fi
    # Lines such as "classify  vase accuracy, ours, worst of pick seeds 22,23,24  99.4873 %  >= 99.5  NO".
    mapfile -t acc < <(awk '/^classify .* accuracy, ours, worst of pick seeds [0-9]/ {
        for (i = 1; i <= NF; i++) if ($(i + 1) == "%") { print $i; break } }' <<<"$out")
    mapfile -t rev < <(awk '/^classify .* accuracy, ours after review .* worst of pick seeds/ {
        for (i = 1; i <= NF; i++) if ($(i + 1) == "%") { print $i; break } }' <<<"$out")
    if [[ ${#acc[@]} -ne 3 || ${#rev[@]} -ne 3 ]]; then
        echo "seed $s: expected three scenes' accuracies, got ${#acc[@]} and ${#rev[@]} after review" >&2
        exit 1
    fi
    printf '| %d | %.2f / %.2f / %.2f %% | %.2f / %.2f / %.2f %% |\n' "$s" "${acc[@]}" "${rev[@]}"
    all+=("${acc[@]}")
    reviewed+=("${rev[@]}")
done
summary() {
    sort -g | awk -v what="$1" '
        { v[NR] = $1; if ($1 < 99.5) under++ }
        END { printf "%s: %d cases, %d under 99.5 %%, worst %.2f %%, median %.2f %%\n", what, NR, under, v[1], (NR % 2 ? v[(NR + 1) / 2] : (v[NR / 2] + v[NR / 2 + 1]) / 2) }'
}
printf '%s\n' "${all[@]}" | summary "as classified"
printf '%s\n' "${reviewed[@]}" | summary "after review"

