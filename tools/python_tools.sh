#!/usr/bin/env bash
# Installs the independent Python readers the diagnostic tests check SuPerMVO against (the
# official iceoryx2 bindings, the mcap reader with its protobuf decoders, a WebSocket client)
# into the cache ($SUPERMVO_CACHE or ~/.cache/supermvo)/python-tools, pinned; a second run
# installs nothing. Use them with PYTHONPATH=<that folder>.
set -euo pipefail
cache="${SUPERMVO_CACHE:-${XDG_CACHE_HOME:-$HOME/.cache}/supermvo}"
target="$cache/python-tools"
pins=(iceoryx2==0.10.0 mcap==1.6.0 mcap-protobuf-support==0.6.0 protobuf==7.36.2 websockets==17.4 pillow==12.0.0)
stamp="$target/.pins"
if [ -f "$stamp" ] && [ "$(cat "$stamp")" = "${pins[*]}" ]; then
  exit 0
fi
echo "python_tools: installing ${pins[*]} into $target"
rm -rf "$target"
python3 -m pip install --quiet --disable-pip-version-check --target "$target" "${pins[@]}"
echo "${pins[*]}" > "$stamp"
