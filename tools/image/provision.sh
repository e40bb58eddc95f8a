#!/usr/bin/env bash
# Provisions a stage machine's image before it is written to the machine's disk (or a copy
# the emulated machine boots): the data partition's contents, the kernel command line.
#
#   tools/image/provision.sh IMAGE [--data DIR] [--kernel-args ARGS]
#
# --data DIR: a new data file system holding DIR, replacing what the partition held. DIR is
#   what the machine mounts at /var: lib/restage-etc/ (appliance.toml, trust/*.pem: /etc/restage
#   on the machine), lib/restage/ (the appliance's state: active.bundle, the ledger).
# --kernel-args ARGS: appended to every boot entry's command line (e.g. video=NAME:WxH@60e to
#   force on an output whose projector reports no modes).
# Needs mtools, e2fsprogs, util-linux (partx); no loop devices, no root.
set -euo pipefail
fail() { echo "provision.sh: $*" >&2; exit 1; }
# shellcheck source=tools/image/uuid.sh
. "$(dirname "$0")/uuid.sh"
img="${1:-}"; [ -f "$img" ] || fail "usage: provision.sh IMAGE [--data DIR] [--kernel-args ARGS] (no image at '$img')"
shift
data=""; args=""
while [ $# -gt 0 ]; do
    case "$1" in
        --data) data="$2"; [ -d "$data" ] || fail "--data $data is not a folder"; shift 2 ;;
        --kernel-args) args="$2"; shift 2 ;;
        *) fail "unknown argument $1" ;;
    esac
done
part_of() {
    local n
    n="$(partx -g -o NR,NAME "$img" | awk -v want="$1" '$2 == want { print $1 }')"
    [ -n "$n" ] || fail "$img has no partition named $1 (not a restage image?)"
    partx -g -o START,SECTORS -n "$n" "$img"
}
if [ -n "$data" ]; then
    read -r start sectors <<<"$(part_of restage-data)"
    # mkfs writes the file system straight into the partition's byte range, filled from DIR.
    # (Ids from the image's name: the same image and DIR give the same bytes.)
    mkfs.ext4 -q -F -L restage-data -d "$data" -U "$(uuid "restage-data $(basename "$img")")" \
        -E offset=$(( start * 512 )),hash_seed="$(uuid "restage-data-hash $(basename "$img")")" \
        "$img" $(( sectors / 2 ))k || fail "mkfs.ext4 of the data partition failed"
    if [ -n "${SOURCE_DATE_EPOCH:-}" ]; then
        # A reproducible build (build.sh): mkfs.ext4 -d copies each file's change time, which
        # no one can set on the source; set it in the new file system instead.
        errors="$( (cd "$data" && find . -mindepth 1 | sed 's|^\.||' | while read -r p; do
            echo "sif \"$p\" ctime @$SOURCE_DATE_EPOCH"
        done; echo "sif / ctime @$SOURCE_DATE_EPOCH") |
            debugfs -w -f - "$img?offset=$(( start * 512 ))" 2>&1 >/dev/null | grep -v '^debugfs [0-9]' || true)"
        [ -z "$errors" ] || fail "debugfs could not set the data file system's change times: $errors"
    fi
    echo "provision.sh: data partition of $img from $data"
fi
if [ -n "$args" ]; then
    read -r start _ <<<"$(part_of esp)"
    esp="$img@@$(( start * 512 ))"
    export MTOOLS_SKIP_CHECK=1
    for entry in $(mdir -b -i "$esp" ::/loader/entries/ | sed 's|.*/||' | grep '\.conf$'); do
        tmp="$(mktemp)"
        mtype -i "$esp" "::/loader/entries/$entry" | tr -d '\r' | sed "/^options /s|\$| $args|" > "$tmp"
        mcopy -o -i "$esp" "$tmp" "::/loader/entries/$entry"
        echo "provision.sh: $entry: $(grep '^options ' "$tmp")"
        rm -f "$tmp"
    done
fi
