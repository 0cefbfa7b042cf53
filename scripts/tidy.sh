#!/usr/bin/env bash
# SPDX-License-Identifier: Apache-2.0
# clang-tidy (Debian's clang-tidy-14) with the repository's .clang-tidy on the
# project's C++ sources (io, gmf, splat, apps; not the tests, and not the CUDA
# files, which clang cannot parse with nvcc's flags); every warning an error.
#
#   bash scripts/tidy.sh          the sources changed since the commit named in
#                                 .ci/tidy-clean (one whose sources were all
#                                 checked clean), committed or not; a changed header
#                                 checks its own .cpp. scripts/test.sh runs this.
#   bash scripts/tidy.sh --all    every source (~15 min on 2 cores); when it
#                                 passes, write HEAD's commit to .ci/tidy-clean.
#   bash scripts/tidy.sh FILE...  those files.
#
# It needs no build: it configures build/tidy (no unity batches, no CUDA, no
# tests) for its compile_commands.json.
set -euo pipefail
cd "$(dirname "$0")/.."
tidy=$(command -v clang-tidy-14 || command -v clang-tidy || true)
if [ -z "$tidy" ]; then
  echo "tidy: clang-tidy is not installed (Debian: apt-get install clang-tidy; scripts/install-deps.sh does)" >&2
  exit 1
fi

files=()
if [ "${1:-}" = "--all" ]; then
  mapfile -t files < <(git ls-files 'io/*.cpp' 'gmf/*.cpp' 'splat/*.cpp' 'apps/*.cpp')
elif [ $# -gt 0 ]; then
  files=("$@")
else
  base=$(tr -d '[:space:]' < .ci/tidy-clean)
  if ! git cat-file -e "$base^{commit}" 2>/dev/null; then
    echo "tidy: .ci/tidy-clean names $base, not a commit of this clone: checking every source" >&2
    exec bash "$0" --all
  fi
  if [ -n "$(git diff --name-only "$base" -- .clang-tidy)" ]; then
    echo "tidy: .clang-tidy changed since $base: checking every source"
    exec bash "$0" --all
  fi
  mapfile -t changed < <({ git diff --name-only "$base" -- io gmf splat apps; git ls-files --others --exclude-standard -- io gmf splat apps; } | sort -u)
  for f in "${changed[@]}"; do
    case "$f" in
      *.cpp) [ -f "$f" ] && files+=("$f") ;;
      *.hpp) [ -f "${f%.hpp}.cpp" ] && files+=("${f%.hpp}.cpp") ;;
    esac
  done
  mapfile -t files < <(printf '%s\n' "${files[@]}" | sort -u | sed '/^$/d')
fi
if [ ${#files[@]} -eq 0 ]; then
  echo "tidy: no C++ source changed since $(tr -d '[:space:]' < .ci/tidy-clean)"
  exit 0
fi

mkdir -p build
cmake -S . -B build/tidy -G Ninja -DCMAKE_BUILD_TYPE=Release -DHISNEGS_CUDA=OFF -DHISNEGS_UNITY_BUILD=OFF \
  -DBUILD_TESTING=OFF -DCMAKE_EXPORT_COMPILE_COMMANDS=ON > build/tidy-configure.log 2>&1 ||
  { cat build/tidy-configure.log >&2; exit 1; }
# The one generated header a source includes (the viewer's assets), made by its
# script directly (through ninja it would wait for the libraries it links).
cmake -DOUT=build/tidy/apps/viewer/generated/apps/viewer/viewer_assets.hpp -DHTML=apps/viewer/viewer.html \
  -DJS=apps/viewer/viewer.js -DZSTD_JS=apps/viewer/vendor/fzstd-0.1.1.umd.js -P cmake/embed_viewer.cmake
echo "tidy: ${#files[@]} source(s) with $("$tidy" --version | grep -o 'version [0-9.]*')"
start=$SECONDS
status=0
printf '%s\n' "${files[@]}" |
  xargs -P "$(nproc)" -n 1 "$tidy" -p build/tidy --quiet --warnings-as-errors='*' \
    --extra-arg=-Wno-unknown-warning-option 2> >(grep -v -E '^[0-9]+ warnings? (and [0-9]+ errors? )?generated' >&2) ||
  status=$?
if [ $status -ne 0 ]; then
  echo "tidy: clang-tidy found problems (above) in $((SECONDS - start)) s" >&2
  exit 1
fi
echo "tidy: clean in $((SECONDS - start)) s"
if [ "${1:-}" = "--all" ] && [ -z "$(git status --porcelain -- io gmf splat apps .clang-tidy)" ]; then
  git rev-parse HEAD > .ci/tidy-clean
  echo "tidy: every source clean at $(git rev-parse --short HEAD): written to .ci/tidy-clean"
fi
