#!/usr/bin/env bash
# SPDX-License-Identifier: Apache-2.0
# Packs everything a bare GPU machine (the NVIDIA driver, a glibc, nothing else of
# ours) needs to run the CUDA tests and benchmarks into .device/ (git-ignored):
#
#   .device/payload.tar.xz   bin/ (hisnegs, the four test executables, stripped),
#                            lib/ (every shared library they load except glibc's and
#                            the driver's libcuda), configs/, data/ (op1 when
#                            ../shared/data has it), VERSION
#   .device/hisnegs          launcher: unpacks on first use, sets LD_LIBRARY_PATH
#   .device/run-tests        launcher: the test executables (gtest arguments pass through)
#   .device/device-check.sh  scripts/device-check.sh, run from the bundle
#
# Usage: bash scripts/device-bundle.sh        (builds the release preset with CUDA first)
#        HISNEGS_BUNDLE_SKIP_BUILD=1 ...      (packs the existing build/release)
#        HISNEGS_BUNDLE_DATA=0 ...            (leaves the op1 stack out)
# The whole of .device/ must stay under 64 MiB (what can be carried to the GPU
# machine); the script fails otherwise and prints the size either way.
set -euo pipefail
cd "$(dirname "$0")/.."
root=$PWD
build=build/release
out=.device
limit=$((64 * 1024 * 1024))

if [[ "${HISNEGS_BUNDLE_SKIP_BUILD:-0}" != 1 ]]; then
  command -v nvcc >/dev/null || [[ -x /usr/local/cuda/bin/nvcc ]] ||
    { echo "device-bundle: nvcc not found: the bundle needs a CUDA build" >&2; exit 2; }
  cmake --preset release -DHISNEGS_CUDA=ON >/dev/null
  cmake --build --preset release
fi
grep -q '^CMAKE_CUDA_COMPILER:STRING=.\+' "$build/CMakeCache.txt" ||
  { echo "device-bundle: $build was configured without CUDA (HISNEGS_CUDA=ON needed)" >&2; exit 2; }

bins=("$build/apps/hisnegs" "$build/tests/io_tests" "$build/tests/gmf_tests" "$build/tests/splat_tests"
      "$build/tests/apps_tests")
for b in "${bins[@]}"; do
  [[ -x "$b" ]] || { echo "device-bundle: $b is missing: build first" >&2; exit 2; }
done

stage=$(mktemp -d)
trap 'rm -rf "$stage"' EXIT
mkdir -p "$stage/bin" "$stage/lib" "$stage/data"
for b in "${bins[@]}"; do
  cp "$b" "$stage/bin/"
  strip --strip-unneeded "$stage/bin/$(basename "$b")"
done

# Every library the executables load, under the name they ask for, except what the
# GPU machine brings: glibc (libc, libm, libpthread, libdl, librt, the loader) and
# the driver (libcuda, libnvidia-*). The CUDA runtime is linked statically.
skip='^(linux-vdso|ld-linux|libc\.so|libm\.so|libpthread\.so|libdl\.so|librt\.so|libutil\.so|libresolv\.so|libcuda\.so|libnvidia-)'
for b in "${bins[@]}"; do
  ldd "$b" | awk '$2 == "=>" && $3 ~ /^\// {print $1, $3}'
done | sort -u | while read -r name path; do
  [[ "$name" =~ $skip ]] && continue
  cp -L "$path" "$stage/lib/$name"
  chmod u+w "$stage/lib/$name"
  strip --strip-unneeded "$stage/lib/$name" 2>/dev/null || true
done
if ldd "$build/apps/hisnegs" | grep -q 'libcudart\.so'; then
  echo "device-bundle: note: the CUDA runtime is linked dynamically; bundled with the rest" >&2
fi

cp -r configs "$stage/configs"
if [[ "${HISNEGS_BUNDLE_DATA:-1}" == 1 && -f ../shared/data/op1_neuron.tif ]]; then
  cp ../shared/data/op1_neuron.tif "$stage/data/"
fi
{
  echo "commit $(git rev-parse --short HEAD 2>/dev/null || echo unknown)$(git diff --quiet 2>/dev/null || echo ' (with local changes)')"
  echo "built $(date -u +%Y-%m-%dT%H:%M:%SZ) on $(. /etc/os-release && echo "$PRETTY_NAME")"
  echo "nvcc $( (nvcc --version 2>/dev/null || /usr/local/cuda/bin/nvcc --version) | sed -n 's/.*release \([0-9.]*\).*/\1/p')"
} >"$stage/VERSION"

rm -rf "$out"
mkdir -p "$out"
# xz -6: 40 s for the ~124 MiB stage on 2 cores, 23 MB; -9 took 106 s for 19.7 MB,
# far below the 64 MiB carry limit either way (CI builds the bundle every run).
tar -C "$stage" -cf - . | xz -6 -T0 >"$out/payload.tar.xz"

# The launchers: unpack once next to themselves (or into $HISNEGS_DEVICE_ROOT), then exec.
cat >"$out/env.sh" <<'EOF'
# Sourced by the launchers: unpacks payload.tar.xz once and points the loader at lib/.
here=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
HISNEGS_DEVICE_ROOT=${HISNEGS_DEVICE_ROOT:-$here/root}
if [[ ! -f "$HISNEGS_DEVICE_ROOT/.unpacked" || "$here/payload.tar.xz" -nt "$HISNEGS_DEVICE_ROOT/.unpacked" ]]; then
  rm -rf "$HISNEGS_DEVICE_ROOT"
  mkdir -p "$HISNEGS_DEVICE_ROOT"
  xz -dc "$here/payload.tar.xz" | tar -C "$HISNEGS_DEVICE_ROOT" -xf -
  touch "$HISNEGS_DEVICE_ROOT/.unpacked"
fi
export LD_LIBRARY_PATH="$HISNEGS_DEVICE_ROOT/lib${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}"
export HISNEGS_TEST_EXE="$HISNEGS_DEVICE_ROOT/bin/hisnegs"
export HISNEGS_TEST_SOURCE_DIR="$HISNEGS_DEVICE_ROOT"
export HISNEGS_TEST_SHARED_DATA="$HISNEGS_DEVICE_ROOT/data"
EOF
cat >"$out/hisnegs" <<'EOF'
#!/usr/bin/env bash
# The bundled hisnegs (scripts/device-bundle.sh).
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/env.sh"
exec "$HISNEGS_DEVICE_ROOT/bin/hisnegs" "$@"
EOF
cat >"$out/run-tests" <<'EOF'
#!/usr/bin/env bash
# Runs the bundled test executables one after the other; arguments go to each
# (e.g. --gtest_filter='*Cuda*'). Exit status: non-zero if any failed.
set -uo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/env.sh"
status=0
for t in io_tests gmf_tests splat_tests apps_tests; do
  echo "run-tests: == $t =="
  (cd "$(mktemp -d)" && "$HISNEGS_DEVICE_ROOT/bin/$t" --gtest_brief=1 "$@") || status=1
done
exit $status
EOF
cp scripts/device-check.sh "$out/device-check.sh"
chmod +x "$out/hisnegs" "$out/run-tests" "$out/device-check.sh"

size=$(du -sb "$out" | cut -f1)
awk -v out="$out" -v s="$size" -v u="$(du -sb "$stage" | cut -f1)" \
  'BEGIN {printf "device-bundle: %s: %.1f MiB (limit 64 MiB); unpacked %.1f MiB\n", out, s / 1048576, u / 1048576}'
if ((size >= limit)); then
  echo "device-bundle: $out is over 64 MiB: leave the data out (HISNEGS_BUNDLE_DATA=0)" >&2
  exit 1
fi
echo "device-bundle: copy $root/$out to the GPU machine and run: bash .device/device-check.sh OUTDIR"
