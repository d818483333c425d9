#!/usr/bin/env bash
# Fails when a C++ or CUDA file of the tree is not as clang-format (.clang-format) writes it, naming the files and
# the command that formats them. Files are git's tracked ones (every C++ file below the tree outside a checkout).
set -uo pipefail
cd "$(dirname "$0")/.."
formatter=$(command -v clang-format-14 || command -v clang-format || true)
if [ -z "$formatter" ]; then
  echo "check_format: clang-format is not installed (scripts/install_deps.sh installs it)" >&2
  exit 1
fi
pattern='\.(cpp|h|cu|cuh)$'
if git rev-parse --is-inside-work-tree >/dev/null 2>&1; then
  mapfile -t files < <(git ls-files | grep -E "$pattern" | grep -v '^third_party/')
else
  mapfile -t files < <(find csrc tests python bench -type f | grep -E "$pattern")
fi
unformatted=()
for f in "${files[@]}"; do
  "$formatter" --dry-run -Werror "$f" >/dev/null 2>&1 || unformatted+=("$f")
done
if [ ${#unformatted[@]} -gt 0 ]; then
  echo "check_format: ${#unformatted[@]} of ${#files[@]} files are not formatted:" >&2
  printf '  %s\n' "${unformatted[@]}" >&2
  echo "format them with: $formatter -i ${unformatted[*]}" >&2
  exit 1
fi
echo "check_format: ${#files[@]} files formatted"
