#!/usr/bin/env bash
# Mutation testing of the safety-critical modules with mutmut 3 ([tool.mutmut] in pyproject.toml).
#
#   tests/mutation/run_mutmut.sh            # every module below, one after the other
#   tests/mutation/run_mutmut.sh route      # one or more of the names below
#
# Each name is a set of mutant-name globs (mutmut 3 names a mutant module.x_function__mutmut_N, or
# module.xǁClassǁmethod__mutmut_N). Results accumulate in mutants/ (a re-run resumes); the summary
# printed at the end counts killed / survived / timeout / other per module over everything run so far.
# Not part of the default test run: it takes minutes to hours on a small machine. One test process at a
# time, niced (MUTMUT_CHILDREN, MUTMUT_NICE to change). Equivalent survivors: tests/mutation/SURVIVORS.md.
# Where a whole module takes too long on a 2-core machine the set names its safety-relevant functions:
# kinematics the drive limits (DiffDrive.limit and the twist -> RPM chain), safety the SafetyLayer and the
# stopping distance, ply_pcd the element / point count checks, recorder_tf the /tf messages.
set -euo pipefail
cd "$(dirname "$0")/../.."
MUTMUT=${MUTMUT:-mutmut}
export OPENBLAS_NUM_THREADS=1 MPLBACKEND=Agg

declare -A GLOBS=(
  [runtime_write]='robchair.runtime.xǁRuntimeǁ_write__mutmut_* robchair.runtime.xǁRuntimeǁ_stale__mutmut_*'
  [safety]='robchair.platform.safety.xǁSafetyLayerǁ* robchair.platform.safety.xǁSafetyLimitsǁstopping_distance__mutmut_*'
  [route]='robchair.route.*'
  [kinematics]='robchair.platform.kinematics.xǁDiffDriveǁlimit__mutmut_* robchair.platform.kinematics.xǁDiffDriveǁ_peak_rpm__mutmut_* robchair.platform.kinematics.xǁDiffDriveǁmotor_rpm__mutmut_* robchair.platform.kinematics.xǁDiffDriveǁwheel_speeds__mutmut_* robchair.platform.kinematics.xǁDiffDriveǁwheel_to_rpm__mutmut_* robchair.platform.kinematics.x__finite__mutmut_*'
  [roboteq]='hw.roboteq.codec.* hw.roboteq.readings.* hw.roboteq.configuration.* hw.roboteq.settings.* hw.roboteq.driver.xǁRoboteqMDC2230ǁset_speeds_rpm__mutmut_* hw.roboteq.driver.xǁRoboteqMDC2230ǁset_commands__mutmut_* hw.roboteq.driver.xǁRoboteqMDC2230ǁ__init____mutmut_*'
  [srf08]='hw.srf08.* hw.sonar_array.*'
  [ply_pcd]='mapping.io.ply.x_read_ply_mesh__mutmut_* mapping.io.ply.x__declared__mutmut_* mapping.io.pcd.x__decode_ascii__mutmut_* mapping.io.pcd.x__decode_binary__mutmut_* mapping.io.pcd.x__decode_compressed__mutmut_*'
  [recorder_tf]='robchair.observers.recorder.xǁRosMessagesǁtf__mutmut_* robchair.observers.recorder.x__quat__mutmut_* robchair.observers.recorder.xǁRunRecorderǁepisode_start__mutmut_* robchair.observers.recorder.xǁRunRecorderǁafter_cycle__mutmut_*'
)
ORDER=(kinematics route runtime_write safety roboteq srf08 ply_pcd recorder_tf)
names=("$@")
[ ${#names[@]} -eq 0 ] && names=("${ORDER[@]}")
for name in "${names[@]}"; do
  globs=${GLOBS[$name]:-}
  if [ -z "$globs" ]; then
    echo "run_mutmut.sh: unknown module set '$name' (expected one of: ${ORDER[*]})" >&2
    exit 2
  fi
  echo "== $name"
  # shellcheck disable=SC2086  # the globs are split into arguments, not expanded by the shell
  (set -f; nice -n "${MUTMUT_NICE:-10}" "$MUTMUT" run --max-children "${MUTMUT_CHILDREN:-1}" $globs) ||
    echo "== $name: mutmut exited $?"
done
echo "== summary (module: killed survived timeout other)"
"$MUTMUT" results --all true | awk -F': ' '
  { name = $1; gsub(/^ +/, "", name); sub(/\.x[_ǁ].*/, "", name); st = $2
    if (st != "killed" && st != "survived" && st != "timeout") st = "other"
    n[name, st]++; mods[name] = 1 }
  END { for (m in mods) printf "%s: %d %d %d %d\n", m, n[m, "killed"], n[m, "survived"], n[m, "timeout"], n[m, "other"] }' | sort
echo "== survivors"
"$MUTMUT" results | grep -v ': killed' || true
