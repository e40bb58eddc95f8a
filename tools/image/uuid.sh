# Sourced by build.sh and provision.sh: `uuid TEXT` prints a version-4-shaped UUID derived from
# TEXT, so that the same image gets the same partition and file system ids every build.
uuid() { printf '%s' "$1" | sha256sum | sed -E 's/^(.{8})(.{4}).(.{3}).(.{3})(.{12}).*/\1-\2-4\3-8\4-\5/'; }
