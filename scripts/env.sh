# shellcheck shell=sh
# Environment of the workspace: `source scripts/env.sh` (bash, zsh or sh) from anywhere.
# Gives: the .venv python (ROS 2 Jazzy wheels), the colcon install/ packages (PYTHONPATH,
# AMENT_PREFIX_PATH), every console script on PATH (platform_sim, calibrator, gsp_demo, ...),
# and DDS kept on loopback in a free domain, claimed for this shell, unless ROS_DOMAIN_ID is set.
# Run `make build` first (`make venv` alone gives the core and ROS wheels, not the nodes).

if [ -n "${BASH_SOURCE:-}" ]; then
  _gsp_env_file=${BASH_SOURCE[0]}
elif [ -n "${ZSH_VERSION:-}" ]; then
  # shellcheck disable=SC2296
  _gsp_env_file=${(%):-%x}
else
  _gsp_env_file=${GSP_ENV_FILE:-scripts/env.sh}
fi
GSP_WS=$(cd "$(dirname "$_gsp_env_file")/.." && pwd)
export GSP_WS
unset _gsp_env_file

if [ ! -x "$GSP_WS/.venv/bin/python" ]; then
  echo "scripts/env.sh: $GSP_WS/.venv is missing; run 'make venv' (or 'make build')" >&2
  return 1 2>/dev/null || exit 1
fi

# colcon's setup scripts read unset variables: relax `set -u` while sourcing them.
case $- in *u*) _gsp_nounset=1; set +u ;; *) _gsp_nounset= ;; esac

VIRTUAL_ENV_DISABLE_PROMPT=${VIRTUAL_ENV_DISABLE_PROMPT:-1}
export VIRTUAL_ENV_DISABLE_PROMPT
# shellcheck disable=SC1091
. "$GSP_WS/.venv/bin/activate"

# The wheels install ament resources under .venv/share; ament_index needs the prefix.
case ":${AMENT_PREFIX_PATH:-}:" in
  *":$GSP_WS/.venv:"*) ;;
  *) AMENT_PREFIX_PATH=$GSP_WS/.venv${AMENT_PREFIX_PATH:+:$AMENT_PREFIX_PATH} ;;
esac
export AMENT_PREFIX_PATH

if [ -f "$GSP_WS/install/local_setup.sh" ]; then
  # shellcheck disable=SC1091
  COLCON_CURRENT_PREFIX=$GSP_WS/install . "$GSP_WS/install/local_setup.sh"
  # There is no `ros2 run`: put every package's lib/<pkg> (its console scripts) on PATH.
  for _gsp_dir in "$GSP_WS"/install/*/lib/*; do
    [ -d "$_gsp_dir" ] || continue
    case $_gsp_dir in */lib/python*) continue ;; esac
    case ":$PATH:" in *":$_gsp_dir:"*) ;; *) PATH=$_gsp_dir:$PATH ;; esac
  done
  unset _gsp_dir
  export PATH
else
  echo "scripts/env.sh: no colcon install/ yet; run 'make build' for the nodes" >&2
fi

ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
export ROS_AUTOMATIC_DISCOVERY_RANGE
# Small matrices: BLAS threads only contend with the nodes on a 2-core machine.
OPENBLAS_NUM_THREADS=${OPENBLAS_NUM_THREADS:-1}
export OPENBLAS_NUM_THREADS
# A free domain, claimed until this shell exits (a small holder process keeps the claim), so
# that no concurrent run draws it; the shell's children share it (docs/faults.md, ROS domains).
if [ -z "${ROS_DOMAIN_ID:-}" ]; then
  # The owner is the shell that sources this file: in bash, $BASHPID is that (sub)shell, so
  # `( . scripts/env.sh; cmd )` frees its domain when the subshell ends ($$ would be the parent
  # shell, which may live for hours). Taken here: inside $(...) it would name the substitution.
  _gsp_owner=${BASHPID:-$$}
  ROS_DOMAIN_ID=$("$GSP_WS/.venv/bin/python" "$GSP_WS/scripts/claim-ros-domain" \
    --owner "$_gsp_owner") || ROS_DOMAIN_ID=''
  unset _gsp_owner
  if [ -n "$ROS_DOMAIN_ID" ]; then
    # This run's claim: a process started from this shell that checks the domain accepts it.
    GSP_ROS_DOMAIN_CLAIMED=$ROS_DOMAIN_ID
    export GSP_ROS_DOMAIN_CLAIMED
  else
    ROS_DOMAIN_ID=$(( $(od -An -N2 -tu2 /dev/urandom | tr -d ' ') % 101 + 1 ))
    echo "scripts/env.sh: no domain claimed; ROS_DOMAIN_ID=$ROS_DOMAIN_ID drawn at random" >&2
  fi
fi
export ROS_DOMAIN_ID

[ -n "$_gsp_nounset" ] && set -u
unset _gsp_nounset
:
