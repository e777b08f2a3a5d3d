#!/usr/bin/env bash
# The default build (the README's two commands) links no system library: every crate it
# builds, tests included, is Rust or C that the crate carries itself. Fails naming each
# crate that finds, binds or links a library from the system (a `-sys` crate not listed
# below, or a helper that looks for one) and the path that pulls it in. Run by `.ci/run`
# before it installs anything; needs only cargo (the lock's crates are downloaded).
set -euo pipefail
cd "$(dirname "$0")/.."

# The -sys crates the default build may hold, each with why it needs nothing installed.
declare -A ALLOWED=(
  [dirs-sys]="Rust over libc (the user's cache directory)"
  [linux-raw-sys]="Rust (Linux's system calls, no C)"
  [libmimalloc-sys]="builds its own copy of mimalloc with cc (the C compiler Rust links with)"
)
# Build helpers that look for a system library or generate bindings to its headers.
HELPERS=(pkg-config bindgen clang-sys cmake vcpkg system-deps build-probe-mpi)

tree() { cargo tree --workspace --locked -e normal,build,dev "$@"; }
# name@version of every crate built, once each.
crates=$(tree --prefix none --format '{p}' | awk '{sub(/^v/, "", $2); print $1 "@" $2}' | sort -u)

bad=()
for spec in $crates; do
  c=${spec%@*}
  helper=0
  for h in "${HELPERS[@]}"; do
    [ "$c" = "$h" ] && helper=1
  done
  if [ "$helper" = 1 ] || { [[ $c == *-sys ]] && [ -z "${ALLOWED[$c]+x}" ]; }; then
    bad+=("$spec")
  fi
done

if [ "${#bad[@]}" -gt 0 ]; then
  echo "the default build needs a system library: ${bad[*]}" >&2
  echo "put the feature that pulls it in behind an opt-in feature (not in [features] default)" >&2
  for c in "${bad[@]}"; do
    echo "--- what pulls in $c:" >&2
    tree -i "$c" --prefix indent --depth 8 >&2 || true
  done
  exit 1
fi
echo "the default build links no system library ($(echo "$crates" | wc -l) crates; -sys crates allowed: ${!ALLOWED[*]})"
