#!/usr/bin/env bash
# Builds the appliance's Debian package (cargo-deb, metadata in appliance/Cargo.toml), installs
# it on this Debian machine with dpkg as an operator would, checks what that gives (an enabled
# unit that systemd accepts, the program, the configuration as a conffile that survives a
# reinstall, the trust directory, the man pages), then purges it and checks nothing is left.
# Needs root and a machine where restage-appliance is not installed yet; CI runs it.
set -euo pipefail
cd "$(dirname "$0")/.."
fail() { echo "deb-check: $*" >&2; exit 1; }
[ "$(id -u)" -eq 0 ] || fail "run as root (it installs the package on this machine)"
! dpkg-query -W restage-appliance >/dev/null 2>&1 || fail "restage-appliance is already installed here; not touching it"
command -v cargo-deb >/dev/null || fail "cargo-deb is missing: cargo install cargo-deb --locked --no-default-features"

# File dates from the commit, so the same commit gives the same package.
export SOURCE_DATE_EPOCH="${SOURCE_DATE_EPOCH:-$(git log -1 --format=%ct)}"
out="$(mktemp -d)"
trap 'rm -rf "$out"; dpkg --purge restage-appliance >/dev/null 2>&1 || true' EXIT
cargo deb -p restage-appliance --quiet --output "$out/restage-appliance.deb" >/dev/null
deb="$out/restage-appliance.deb"
echo "== built $(dpkg-deb -f "$deb" Package) $(dpkg-deb -f "$deb" Version), depends: $(dpkg-deb -f "$deb" Depends)"

dpkg -i "$deb" >/dev/null
unit=/usr/lib/systemd/system/restage-appliance.service
[ -f "$unit" ] || fail "no unit at $unit"
cmp -s "$unit" systemd/restage-appliance.service || fail "$unit is not systemd/restage-appliance.service"
# Enabled as systemd sees it on the installed root (systemd need not be running).
state="$(systemctl --root=/ is-enabled restage-appliance.service || true)"
[ "$state" = enabled ] || fail "the unit is '$state' after dpkg -i, not enabled"
# systemd accepts the unit as installed: ExecStart names the packaged program, every setting parses.
verify_out="$(systemd-analyze verify "$unit" 2>&1)" || true
[ -z "$verify_out" ] || fail "systemd-analyze verify $unit: $verify_out"
want_version="$(cargo metadata --format-version 1 --no-deps | python3 -c 'import json,sys; print(next(p["version"] for p in json.load(sys.stdin)["packages"] if p["name"]=="restage-appliance"))')"
[ "$(/usr/bin/restage-appliance --version)" = "restage-appliance $want_version" ] || fail "restage-appliance --version: $(/usr/bin/restage-appliance --version)"
dpkg-query -W -f='${Conffiles}\n' restage-appliance | grep -q '^ /etc/restage/appliance.toml ' \
    || fail "/etc/restage/appliance.toml is not a conffile"
cmp -s /etc/restage/appliance.toml systemd/restage-appliance.toml || fail "the installed configuration is not the documented one"
zcat /usr/share/man/man1/restage-appliance.1.gz | grep -q '^\.TH restage-appliance 1' || fail "no man page restage-appliance(1)"
# The trust directory comes from tmpfiles.d, as at boot.
systemd-tmpfiles --create restage-appliance.conf
[ "$(stat -c '%a %U' /etc/restage/trust)" = "755 root" ] || fail "/etc/restage/trust: $(stat -c '%a %U' /etc/restage/trust)"
# The installed program reads the installed configuration: with no ledger yet, status says so
# (a configuration it could not parse would fail first, naming the file).
if status_out="$(/usr/bin/restage-appliance status 2>&1)"; then fail "status succeeded without a ledger: $status_out"; fi
grep -q "no ledger at /var/lib/restage/ledger.sqlite" <<<"$status_out" || fail "status: $status_out"

# An operator's edit to the configuration survives reinstalling (an update of the package).
echo '# edited by the operator' >> /etc/restage/appliance.toml
dpkg -i "$deb" >/dev/null
tail -1 /etc/restage/appliance.toml | grep -q 'edited by the operator' || fail "reinstalling replaced the operator's configuration"
[ "$(systemctl --root=/ is-enabled restage-appliance.service || true)" = enabled ] || fail "not enabled after reinstall"

dpkg --purge restage-appliance >/dev/null
for gone in /usr/bin/restage-appliance "$unit" /etc/restage/appliance.toml \
    /etc/systemd/system/multi-user.target.wants/restage-appliance.service; do
    [ ! -e "$gone" ] || fail "$gone is left after dpkg --purge"
done
echo "deb-check ok: installed, enabled, unit verified, conffile kept across reinstall, purged clean"
