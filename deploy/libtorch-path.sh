# Sourced by deploy/local.sh, actors.sh, reproduce.sh and gpu-check.sh:
# binaries built with libtorch (`nets/gpu-torch`, deploy/build-gpu-torch.sh)
# load it at start. When the loader cannot find it, point LD_LIBRARY_PATH at
# the libtorch of python3's torch, the PyTorch they were built against.
use_libtorch_of_python() { # binary
  ldd "$1" 2>/dev/null | grep -q 'libtorch.*not found' || return 0
  local lib
  lib="$(python3 -c 'import os, torch; print(os.path.join(os.path.dirname(torch.__file__), "lib"))' 2>/dev/null)" || {
    echo "$1 needs libtorch, and python3 has no torch to take it from: install the PyTorch it was built against or set LD_LIBRARY_PATH to a libtorch's lib/" >&2
    return 1
  }
  export LD_LIBRARY_PATH="$lib${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}"
  echo "libtorch from $lib" >&2
}
