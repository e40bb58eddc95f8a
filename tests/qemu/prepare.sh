#!/usr/bin/env bash
# Builds the emulated stage machine for tests/tests/kms_qemu.rs and power_qemu.rs: a stock
# Debian kernel (fetched with apt-get download, unpacked with dpkg -x, cached) and an
# initramfs holding busybox, the virtio-gpu modules, the appliance binary with its shared
# libraries, the test payload (config, trust keys, state with the bundle) and tests/qemu/init.
#
#   tests/qemu/prepare.sh OUT_DIR APPLIANCE_BIN PAYLOAD_DIR [disk]
#
# With `disk`, the initramfs also holds the modules of a virtio disk with an ext4 file system
# (virtio_blk, ext4 and what they need, listed in lib/modules/order-disk; init loads them
# when the kernel command line names the disk).
# Writes OUT_DIR/vmlinux (the uncompressed kernel: QEMU boots it through PVH, ~3 s faster
# than the bzImage under software emulation) and OUT_DIR/initrd.cpio. The kernel and its
# modules are cached in ${RESTAGE_QEMU_CACHE:-$HOME/.cache/restage-qemu}.
# Needs: apt-get, dpkg, xz, busybox (busybox-static), cpio, modprobe/depmod (kmod), ldd, strip.
set -euo pipefail

out="$1"; bin="$2"; payload="$3"; variant="${4:-}"
# The modules the machine loads (modprobe adds their dependencies): the display, and for
# the disk variant the virtio disk and ext4 (crc32c_generic: ext4's metadata checksums need
# a crc32c, and the emulated CPU has no SSE4.2 for crc32c_intel).
gpu_modules="virtio_pci virtio-gpu"
disk_modules="virtio_blk crc32c_generic ext4"
here="$(cd "$(dirname "$0")" && pwd)"
cache="${RESTAGE_QEMU_CACHE:-$HOME/.cache/restage-qemu}"
mkdir -p "$out" "$cache"

for tool in apt-get dpkg xz cpio depmod modprobe ldd strip; do
    command -v "$tool" >/dev/null || { echo "prepare.sh: $tool not found" >&2; exit 3; }
done
busybox="$(command -v busybox || true)"
if [ -z "$busybox" ] || ! { ldd "$busybox" 2>&1 || true; } | grep -q "not a dynamic"; then
    echo "prepare.sh: a static busybox is needed (apt-get install busybox-static)" >&2; exit 3
fi

# The kernel: the version linux-image-amd64 depends on, unless one is cached already (a
# cached kernel keeps runs offline and fast; delete the cache to move to a newer one).
# A cache made before the disk modules were kept lacks them: fetched again.
kver="$(ls "$cache" 2>/dev/null | grep -E '^[0-9].*-amd64$' | sort -V | tail -n1 || true)"
cached_ok() {
    [ -n "$kver" ] && [ -s "$cache/$kver/vmlinux" ] || return 1
    for m in $gpu_modules $disk_modules; do
        modprobe -d "$cache/$kver" -S "$kver" --show-depends "$m" >/dev/null 2>&1 || return 1
    done
}
if ! cached_ok; then
    pkg="$(apt-cache depends linux-image-amd64 | sed -n 's/^ *Depends: \(linux-image-[0-9].*-amd64\)$/\1/p' | head -n1)"
    [ -n "$pkg" ] || { echo "prepare.sh: apt-cache does not know linux-image-amd64 (run apt-get update)" >&2; exit 3; }
    kver="${pkg#linux-image-}"
    tmp="$(mktemp -d "$cache/dl.XXXXXX")"
    (cd "$tmp" && apt-get download -q "$pkg" >/dev/null 2>&1) || { echo "prepare.sh: apt-get download $pkg failed" >&2; exit 3; }
    dpkg -x "$tmp"/*.deb "$tmp/x"
    mkdir -p "$tmp/k/lib"
    mv "$tmp/x/lib/modules" "$tmp/k/lib/modules"
    img="$tmp/x/boot/vmlinuz-$kver"
    # The bzImage carries the kernel as an xz stream: find it and unpack the ELF vmlinux.
    for off in $(LC_ALL=C grep -obUaP '\xfd7zXZ\x00' "$img" | cut -d: -f1); do
        tail -c +"$((off + 1))" "$img" | xz -dc > "$tmp/k/vmlinux" 2>/dev/null || true
        if [ "$(head -c 4 "$tmp/k/vmlinux" | od -An -c | tr -d ' ')" = '177ELF' ]; then break; fi
    done
    [ -s "$tmp/k/vmlinux" ] || { echo "prepare.sh: no vmlinux found in $img" >&2; exit 3; }
    # Only the modules the machine loads are kept (the package has 400 MB of them).
    depmod -b "$tmp/k" "$kver"
    keep="$(for m in $gpu_modules $disk_modules; do
        modprobe -d "$tmp/k" -S "$kver" --show-depends "$m" | awk '$1 == "insmod" { print $2 }'
    done | sort -u)"
    find "$tmp/k/lib/modules/$kver/kernel" -name '*.ko*' -type f | sort | comm -23 - <(echo "$keep") | xargs rm -f
    depmod -b "$tmp/k" "$kver"
    rm -rf "$cache/$kver"
    mv "$tmp/k" "$cache/$kver"
    rm -rf "$tmp"
fi
kdir="$cache/$kver"
cp -f "$kdir/vmlinux" "$out/vmlinux"

root="$out/root"
rm -rf "$root"
mkdir -p "$root"/{bin,sbin,dev,proc,sys,tmp,lib/modules,usr/bin,restage}
cp "$busybox" "$root/bin/busybox"
cp "$here/init" "$root/init"
chmod +x "$root/init"

# The modules virtio-gpu needs, in load order (modprobe resolves the dependencies); for the
# disk variant then those of the disk not already in the first list.
modules_in_order() {
    for m in "$@"; do
        modprobe -d "$kdir" -S "$kver" --show-depends "$m" | awk '$1 == "insmod" { print $2 }'
    done
}
: > "$root/lib/modules/order"
modules_in_order $gpu_modules | awk '!seen[$0]++' | while read -r ko; do
    cp "$ko" "$root/lib/modules/"
    basename "$ko" >> "$root/lib/modules/order"
done
if [ "$variant" = disk ]; then
    : > "$root/lib/modules/order-disk"
    modules_in_order $disk_modules | awk '!seen[$0]++' | while read -r ko; do
        grep -qxF "$(basename "$ko")" "$root/lib/modules/order" && continue
        # ext4's soft dependency; the emulated CPU lacks SSE4.2, crc32c_generic serves.
        case "$(basename "$ko")" in crc32c-intel.ko*) continue ;; esac
        cp "$ko" "$root/lib/modules/"
        basename "$ko" >> "$root/lib/modules/order-disk"
    done
fi

# The appliance, stripped (debug builds carry ~100 MB of debug info), and its libraries.
strip -o "$root/usr/bin/restage-appliance" "$bin"
ldd "$bin" | awk '/=>/ { print $3 } !/=>/ && $1 ~ /^\// { print $1 }' | while read -r lib; do
    [ -e "$lib" ] || continue
    mkdir -p "$root$(dirname "$lib")"
    cp -L "$lib" "$root$lib"
done
# The dynamic loader's canonical path.
if [ -e /lib64/ld-linux-x86-64.so.2 ]; then mkdir -p "$root/lib64"; cp -L /lib64/ld-linux-x86-64.so.2 "$root/lib64/"; fi

cp -a "$payload/." "$root/restage/"
(cd "$root" && find . -print0 | cpio --null -o -H newc --quiet) > "$out/initrd.cpio"
rm -rf "$root"
echo "kernel $kver"
