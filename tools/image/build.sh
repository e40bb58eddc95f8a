#!/usr/bin/env bash
# Builds the stage machine's disk image: x86-64 UEFI, Debian bookworm from its packages
# (mmdebstrap) with the appliance's own package, a read-only squashfs root in slot A of two,
# systemd-boot with boot counting, and a data partition for everything that changes.
#
#   tools/image/build.sh OUT_DIR [--version V] [--deb FILE] [--update-key KEY.pem] [--update-trust PUB.pem]
#                                [--pin PACKAGES]
#
# Writes OUT_DIR/restage-V.img (GPT: ESP, restage-root-a, restage-root-b, restage-data; sparse),
# OUT_DIR/restage-V.update/ (root.squashfs, vmlinuz, initrd: slot A's contents, the update that
# installs this version on a machine running an older one; signed with --update-key, which
# `restage-appliance update install` checks against the machine's /etc/restage/update-trust),
# and OUT_DIR/restage-V.packages (every package and version inside). V defaults to the
# appliance's version; --deb takes a package built already (else cargo-deb builds one);
# --update-trust puts a public key into the image's update-trust; --pin rebuilds from an
# earlier build's restage-V.packages, every package at the version it names (apt must still
# find those versions: the same archive state, or a snapshot of it). Dates come from
# SOURCE_DATE_EPOCH (default: the last commit's), so the same commit and the same archive give
# the same root file system.
# Needs root and the apt packages of tools/image/host-packages. Downloads go through apt
# from the Debian archive and are kept in ${RESTAGE_IMAGE_CACHE:-$HOME/.cache/restage-image}.
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
repo="$(cd "$here/../.." && pwd)"
fail() { echo "build.sh: $*" >&2; exit 1; }
# shellcheck source=tools/image/uuid.sh
. "$here/uuid.sh"

out="${1:-}"; [ -n "$out" ] || fail "usage: build.sh OUT_DIR [--version V] [--deb FILE] [--update-key KEY.pem] [--update-trust PUB.pem] [--pin PACKAGES]"
shift
version=""; deb=""; update_key=""; update_trust=""; pin=""
while [ $# -gt 0 ]; do
    case "$1" in
        --version) version="$2"; shift 2 ;;
        --deb) deb="$2"; shift 2 ;;
        --update-key) update_key="$(realpath "$2")"; shift 2 ;;
        --update-trust) update_trust="$(realpath "$2")"; [ -f "$update_trust" ] || fail "no key at $2"; shift 2 ;;
        --pin) pin="$(realpath "$2")"; [ -f "$pin" ] || fail "no package list at $2"; shift 2 ;;
        *) fail "unknown argument $1" ;;
    esac
done
[ "$(id -u)" -eq 0 ] || fail "run as root (mmdebstrap's root mode, device nodes in the root file system)"
for tool in mmdebstrap mksquashfs mkfs.vfat mcopy mmd sfdisk mkfs.ext4 partx; do
    command -v "$tool" >/dev/null || fail "$tool not found: apt-get install $(grep -v '^#' "$here/host-packages" | tr '\n' ' ')"
done
export SOURCE_DATE_EPOCH="${SOURCE_DATE_EPOCH:-$(git -C "$repo" log -1 --format=%ct)}"
# Every file system gets the same times and ids from the same inputs.
export E2FSPROGS_FAKE_TIME="$SOURCE_DATE_EPOCH"
cache="${RESTAGE_IMAGE_CACHE:-$HOME/.cache/restage-image}"
mkdir -p "$out" "$cache/debs"
out="$(cd "$out" && pwd)"
t0=$(date +%s)

if [ -z "$deb" ]; then
    command -v cargo-deb >/dev/null || fail "cargo-deb is missing: cargo install cargo-deb --locked --no-default-features"
    (cd "$repo" && cargo deb -p restage-appliance --quiet --output "$out/restage-appliance.deb" >/dev/null)
    deb="$out/restage-appliance.deb"
fi
deb="$(cd "$(dirname "$deb")" && pwd)/$(basename "$deb")"
[ -n "$version" ] || version="$(dpkg-deb -f "$deb" Version)"
name="restage-$version"
echo "== image $name (appliance $(dpkg-deb -f "$deb" Version), SOURCE_DATE_EPOCH=$SOURCE_DATE_EPOCH)"

work="$(mktemp -d "$out/.work.XXXXXX")"
# RESTAGE_IMAGE_KEEP=1 keeps the work folder (the root file system, the ESP) to look into.
[ "${RESTAGE_IMAGE_KEEP:-}" = 1 ] || trap 'rm -rf "$work"' EXIT
root="$work/root"
include="$(grep -v '^\s*#' "$here/packages" | grep -v '^\s*$' | tr '\n' ',')"
pin_hooks=()
if [ -n "$pin" ]; then
    # Every package of the earlier build held at its version by apt preferences (not by
    # name=version requests, which would mark every dependency as asked for and so change
    # apt's own records in the image); removed before the root is packed. The appliance
    # comes from --deb.
    awk 'NF == 2 && $1 != "restage-appliance" { printf "Package: %s\nPin: version %s\nPin-Priority: 1001\n\n", $1, $2 }' \
        "$pin" > "$work/pins"
    [ -s "$work/pins" ] || fail "$pin lists no packages (expected lines \"NAME VERSION\")"
    pin_hooks=(--setup-hook="mkdir -p \"\$1\"/etc/apt/preferences.d && cp $work/pins \"\$1\"/etc/apt/preferences.d/restage-pins"
        --customize-hook="rm \"\$1\"/etc/apt/preferences.d/restage-pins")
fi
# The package cache is handed in before and taken back after, so a rebuild downloads only what
# changed (the recipe of mmdebstrap(1), "--skip=essential/unlink").
mmdebstrap --mode=root --variant=minbase --include="$include" \
    --skip=essential/unlink \
    --setup-hook='mkdir -p "$1"/var/cache/apt/archives/' \
    --setup-hook="sync-in $cache/debs /var/cache/apt/archives/" \
    "${pin_hooks[@]}" \
    --customize-hook="sync-out /var/cache/apt/archives $cache/debs" \
    --customize-hook="copy-in $deb /tmp" \
    --customize-hook="chroot \"\$1\" dpkg -i /tmp/$(basename "$deb")" \
    --customize-hook="$here/customize.sh \"\$1\" $version" \
    --customize-hook="chroot \"\$1\" dpkg-query -W -f='\${Package} \${Version}\n' > $work/packages" \
    bookworm "$root" >"$work/mmdebstrap.log" 2>&1 || { tail -n 30 "$work/mmdebstrap.log" >&2; fail "mmdebstrap failed"; }
sort "$work/packages" > "$out/$name.packages"
# A pin on a version the archive no longer has is passed over by apt: compare, and stop.
if [ -n "$pin" ] && ! diff <(grep -v '^restage-appliance ' "$pin" | sort) \
    <(grep -v '^restage-appliance ' "$out/$name.packages") > "$work/pin.diff"; then
    fail "the image's packages are not those of $pin (versions the archive no longer has?): $(grep '^[<>]' "$work/pin.diff" | head -n 6 | tr '\n' ' ')"
fi
echo "== root file system: $(wc -l < "$out/$name.packages") packages ($(( $(date +%s) - t0 )) s)"

# --- What a running appliance never needs (the root was customised inside mmdebstrap by
# customize.sh, with /proc and /dev mounted for update-initramfs).
kver="$(ls "$root/usr/lib/modules" | sort -V | tail -n1)"
# One machine id for every machine of this image, written here as mmdebstrap empties it as it
# finishes: PID 1 reads it before the data partition is mounted, and a read-only root cannot
# keep a generated one (with a new id every boot the journal would start a new folder every
# boot, outside its size cap). The machines have no network, where a shared id could matter.
printf '%s\n' "$(printf 'restage stage machine' | sha256sum | cut -c1-32)" > "$root/etc/machine-id"
# Package lists and caches, documentation, locales.
rm -rf "$root"/var/cache/apt/* "$root"/var/lib/apt/lists/* "$root"/tmp/* "$root"/var/log/* \
    "$root"/usr/share/doc/*/changelog* "$root"/usr/share/locale/* "$root"/usr/share/man/?? \
    "$root"/usr/share/man/??_?? "$root"/etc/*- "$root"/var/cache/debconf/*-old
# Kernel modules the stage machine has no use for (networking, sound, tuners and cameras,
# radios, file systems it never mounts), then anything left that needed one of them. The
# display, input, storage, USB and watchdog drivers stay (drivers/media/cec and rc too: the
# DRM display helpers need them).
km="$root/usr/lib/modules/$kver/kernel"
rm -rf "$km"/net "$km"/sound "$km"/drivers/net "$km"/drivers/bluetooth "$km"/drivers/staging \
    "$km"/drivers/infiniband "$km"/drivers/isdn "$km"/drivers/iio "$km"/drivers/md "$km"/drivers/target \
    "$km"/drivers/nfc "$km"/drivers/atm "$km"/drivers/ieee802154 "$km"/drivers/edac "$km"/drivers/vfio \
    "$km"/drivers/media/{usb,pci,dvb-frontends,dvb-core,tuners,i2c,platform,radio,common,mmc,spi,test-drivers,firewire}
find "$km/fs" -mindepth 1 -maxdepth 1 -type d \
    ! -name ext4 ! -name squashfs ! -name fat ! -name exfat ! -name nls ! -name jbd2 ! -name mbcache \
    ! -name autofs ! -name efivarfs -exec rm -rf {} +
# modules.dep as the package shipped it lists each module's dependencies: a module one of
# whose dependencies is gone goes too, until none is left (Debian's System.map is a stub, so
# depmod cannot check symbols).
dep="$root/usr/lib/modules/$kver/modules.dep"
while :; do
    broken="$(cd "$root/usr/lib/modules/$kver" && find kernel -name '*.ko*' | awk -F': *' '
        NR == FNR { have[$0] = 1; next }
        $1 in have { n = split($2, d, " "); for (i = 1; i <= n; i++) if (!(d[i] in have)) { print $1; next } }
        ' - "$dep")"
    [ -n "$broken" ] || break
    echo "== left out $(echo "$broken" | wc -l) more modules that needed one left out (first: $(echo "$broken" | sed 's|.*/||' | head -n 5 | tr '\n' ' ')...)"
    (cd "$root/usr/lib/modules/$kver" && echo "$broken" | xargs rm -f)
done
depmod -b "$root" "$kver"
# What the stage machine cannot do without must have survived.
for m in autofs4 efivarfs virtio-gpu i915 amdgpu nouveau i6300esb iTCO_wdt sp5100_tco usb-storage uas xhci-pci sd_mod vfat exfat nls_cp437 nls_utf8 squashfs ext4 hid-generic usbhid ftdi_sio cp210x pl2303 cdc-acm; do
    modinfo -b "$root" -k "$kver" -F filename "$m" >/dev/null 2>&1 || fail "kernel module $m is missing from the image"
done
find "$root" -newermt "@$SOURCE_DATE_EPOCH" -print0 | xargs -0r touch --no-dereference --date="@$SOURCE_DATE_EPOCH"

# --- Slot A's contents (and the update's): the kernel and initramfs (booted from the ESP) and
# the squashfs root.
upd="$out/$name.update"
rm -rf "$upd"
mkdir -p "$upd"
cp "$root/boot/vmlinuz-$kver" "$upd/vmlinuz"
cp "$root/boot/initrd.img-$kver" "$upd/initrd"
# SOURCE_DATE_EPOCH sets every time in it. The mount points stay, empty.
mksquashfs "$root" "$upd/root.squashfs" -comp zstd -Xcompression-level 15 -noappend \
    -quiet -no-progress -wildcards -e 'boot/*' 'proc/*' 'sys/*' 'dev/*' 'run/*' 'tmp/*' >/dev/null
echo "== root squashfs $(du -m "$upd/root.squashfs" | cut -f1) MiB ($(( $(date +%s) - t0 )) s)"
if [ -n "$update_key" ]; then
    # Signed by the appliance program of the package itself (the same code that verifies).
    dpkg-deb -x "$deb" "$work/deb"
    "$work/deb/usr/bin/restage-appliance" update sign "$upd" --version "$version" --key "$update_key"
fi

# --- The disk: GPT with fixed ids (derived from the version, so two builds agree).
img="$out/$name.img"
rm -f "$img"
# Sizes in MiB: the ESP holds two slots' kernels and initramfs images; a root slot holds a
# squashfs with room to grow; the data partition grows to the disk's end at first boot.
esp_mb=128; slot_mb=768; data_mb=512
truncate -s $(( (1 + esp_mb + 2 * slot_mb + data_mb + 1) * 1024 * 1024 )) "$img"
sfdisk -q "$img" <<EOF
label: gpt
label-id: $(uuid "$name disk")
first-lba: 2048
size=${esp_mb}MiB, type=C12A7328-F81F-11D2-BA4B-00A0C93EC93B, uuid=$(uuid "$name esp"), name=esp
size=${slot_mb}MiB, type=4F68BCE3-E8CD-4DB1-96E7-FBCAF984B709, uuid=$(uuid "$name root-a"), name=restage-root-a
size=${slot_mb}MiB, type=4F68BCE3-E8CD-4DB1-96E7-FBCAF984B709, uuid=$(uuid "$name root-b"), name=restage-root-b
size=${data_mb}MiB, type=0FC63DAF-8483-4772-8E79-3D69D8477DE4, uuid=$(uuid "$name data"), name=restage-data
EOF
part() { partx -g -o START,SECTORS -n "$1" "$img"; }
read -r esp_start esp_sectors <<<"$(part 1)"
read -r a_start _ <<<"$(part 2)"
read -r data_start data_sectors <<<"$(part 4)"

# ESP: systemd-boot (from the image's own systemd-boot-efi), no menu, slot A's entry with
# boot counting off (the built image is known good; an update's entry counts).
esp="$work/esp"
mkdir -p "$esp/EFI/BOOT" "$esp/EFI/systemd" "$esp/loader/entries" "$esp/restage/a"
cp "$root/usr/lib/systemd/boot/efi/systemd-bootx64.efi" "$esp/EFI/BOOT/BOOTX64.EFI"
cp "$root/usr/lib/systemd/boot/efi/systemd-bootx64.efi" "$esp/EFI/systemd/systemd-bootx64.efi"
cp "$upd/vmlinuz" "$esp/restage/a/vmlinuz"
cp "$upd/initrd" "$esp/restage/a/initrd"
printf 'timeout 0\nconsole-mode keep\neditor no\nauto-entries no\nauto-firmware no\n' > "$esp/loader/loader.conf"
"$here/entry.sh" a "$version" "" > "$esp/loader/entries/restage-a.conf"
find "$esp" -exec touch --date="@$SOURCE_DATE_EPOCH" {} +
esp_img="$work/esp.img"
mkfs.vfat --invariant -C -F 32 -n ESP -i "$(uuid "$name esp-fs" | cut -c1-8)" "$esp_img" $(( esp_sectors / 2 )) >/dev/null
MTOOLS_SKIP_CHECK=1 mcopy -s -m -i "$esp_img" "$esp"/* ::/
dd if="$esp_img" of="$img" bs=512 seek="$esp_start" conv=notrunc,sparse status=none
dd if="$upd/root.squashfs" of="$img" bs=512 seek="$a_start" conv=notrunc status=none

# Data partition: the factory configuration and an empty trust folder (the museum provisions
# keys and a bundle with tools/image/provision.sh, or through the bundle inbox).
data="$work/data"
mkdir -p "$data/lib/restage-etc/trust" "$data/lib/restage-etc/update-trust"
cp -a "$root/usr/share/factory/etc/restage/." "$data/lib/restage-etc/"
[ -z "$update_trust" ] || cp "$update_trust" "$data/lib/restage-etc/update-trust/"
# mkfs.ext4 -d copies each file's times (the access time too): all at SOURCE_DATE_EPOCH.
find "$data" -exec touch --no-dereference --date="@$SOURCE_DATE_EPOCH" {} +
"$here/provision.sh" "$img" --data "$data" >/dev/null
echo "== $img: $(du -m --apparent-size "$img" | cut -f1) MiB ($(du -m "$img" | cut -f1) MiB used), built in $(( $(date +%s) - t0 )) s"
