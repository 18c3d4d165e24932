#!/usr/bin/env bash
# Checks that engine/ folders depend one way (docs/architecture.md, "Folders"): each folder
# includes only itself and folders of a lower layer. Prints each offending include and exits 1.
set -euo pipefail
cd "$(dirname "$0")/.."
declare -A layer=([core]=0 [mesh]=1 [fem]=2 [scene]=2 [tools]=3 [particles]=3 [solver]=3 [sim]=4
                  [haptics]=5 [analysis]=5)
status=0
for dir in engine/*/; do
  from=$(basename "$dir")
  [ -n "${layer[$from]+x}" ] || { echo "engine/$from: no layer (add it to $0)"; status=1; continue; }
  while IFS=: read -r file to; do
    [ "$to" = "$from" ] && continue
    if [ -z "${layer[$to]+x}" ] || [ "${layer[$to]}" -ge "${layer[$from]}" ]; then
      echo "$file includes engine/$to/: engine/$from/ may include only lower layers"
      status=1
    fi
  done < <(grep -o '#include "engine/[a-z_]*/' "$dir"*.h "$dir"*.cpp 2>/dev/null |
           sed 's|#include "engine/||; s|/$||')
done
[ $status -eq 0 ] && echo "engine layers: ok (core < mesh < fem, scene < tools, particles, solver < sim < haptics, analysis)"
exit $status
