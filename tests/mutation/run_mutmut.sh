#!/usr/bin/env bash
# Mutation testing of the safety-critical modules with mutmut 3 ([tool.mutmut] in pyproject.toml).
#
#   tests/mutation/run_mutmut.sh            # every module below, one after the other
#   tests/mutation/run_mutmut.sh route      # one or more of the names below
#
# Each name is a set of mutant-name globs (mutmut 3 names a mutant module.x_function__mutmut_N, or
# module.xǁClassǁmethod__mutmut_N). Results accumulate in mutants/; naming a set runs its mutants
# again (mutmut re-runs every mutant it is given by name), and the summary printed at the end counts
# killed / survived / timeout / other per module over everything run so far. roboteq and srf08 name
# the functions that carry the safety: the command builders and flag words, the readings' scaling and
# field counts, the configuration values and gains, the protections, the speed/command limits; the SRF08
# range register, ranging, busy wait and readings, and the 65 ms firing slots. Re-check one mutant:
# ROBCHAIR_HYPOTHESIS_PROFILE=mutation mutmut run NAME (the profile lifts Hypothesis's deadlines and
# too-slow check, which mutmut's line tracing trips on a loaded machine).
# Not part of the default test run: it takes minutes to hours on a small machine. One test process at a
# time, niced (MUTMUT_CHILDREN, MUTMUT_NICE to change). Equivalent survivors: tests/mutation/SURVIVORS.md.
# Where a whole module takes too long on a 2-core machine the set names its safety-relevant functions:
# kinematics the drive limits (DiffDrive.limit and the twist -> RPM chain), safety the SafetyLayer and the
# stopping distance, ply_pcd the element / point count checks, recorder_tf the /tf messages.
set -euo pipefail
cd "$(dirname "$0")/../.."
MUTMUT=${MUTMUT:-mutmut}
export OPENBLAS_NUM_THREADS=1 MPLBACKEND=Agg ROBCHAIR_HYPOTHESIS_PROFILE=${ROBCHAIR_HYPOTHESIS_PROFILE:-mutation}

declare -A GLOBS=(
  [runtime_write]='robchair.runtime.xǁRuntimeǁ_write__mutmut_* robchair.runtime.xǁRuntimeǁ_stale__mutmut_*'
  [safety]='robchair.platform.safety.xǁSafetyLayerǁ* robchair.platform.safety.xǁSafetyLimitsǁstopping_distance__mutmut_*'
  [route]='robchair.route.*'
  [kinematics]='robchair.platform.kinematics.xǁDiffDriveǁlimit__mutmut_* robchair.platform.kinematics.xǁDiffDriveǁ_peak_rpm__mutmut_* robchair.platform.kinematics.xǁDiffDriveǁmotor_rpm__mutmut_* robchair.platform.kinematics.xǁDiffDriveǁwheel_speeds__mutmut_* robchair.platform.kinematics.xǁDiffDriveǁwheel_to_rpm__mutmut_* robchair.platform.kinematics.x__finite__mutmut_*'
  [roboteq]='hw.roboteq.codec.x__channel__mutmut_*
    hw.roboteq.codec.x_set_speed__mutmut_*
    hw.roboteq.codec.x_go__mutmut_*
    hw.roboteq.codec.x_emergency_stop__mutmut_*
    hw.roboteq.codec.x_release_stop__mutmut_*
    hw.roboteq.codec.x_query__mutmut_*
    hw.roboteq.codec.x_set_config__mutmut_*
    hw.roboteq.codec.x_get_config__mutmut_*
    hw.roboteq.codec.x__decode_bits__mutmut_*
    hw.roboteq.codec.x__encode_bits__mutmut_*
    hw.roboteq.codec.x_decode_fault_flags__mutmut_*
    hw.roboteq.codec.x_encode_fault_flags__mutmut_*
    hw.roboteq.codec.x_decode_status_flags__mutmut_*
    hw.roboteq.codec.x_encode_status_flags__mutmut_*
    hw.roboteq.codec.x_decode_motor_flags__mutmut_*
    hw.roboteq.codec.x_encode_motor_flags__mutmut_*
    hw.roboteq.codec.x_wrap_int32__mutmut_*
    hw.roboteq.codec.xǁCommandǁ*
    hw.roboteq.readings.xǁRoboteqReadingsǁread_encoder_counts__mutmut_*
    hw.roboteq.readings.xǁRoboteqReadingsǁread_speeds_rpm__mutmut_*
    hw.roboteq.readings.xǁRoboteqReadingsǁread_faults_word__mutmut_*
    hw.roboteq.readings.xǁRoboteqReadingsǁread_faults__mutmut_*
    hw.roboteq.readings.xǁRoboteqReadingsǁread_voltages__mutmut_*
    hw.roboteq.readings.xǁRoboteqReadingsǁread_amps__mutmut_*
    hw.roboteq.readings.xǁRoboteqReadingsǁread_temperatures__mutmut_*
    hw.roboteq.readings.x__flag_word__mutmut_*
    hw.roboteq.configuration.xǁRoboteqConfigurationǁ_write_configuration__mutmut_*
    hw.roboteq.configuration.xǁRoboteqConfigurationǁfirmware_gains__mutmut_*
    hw.roboteq.configuration.xǁRoboteqConfigurationǁset_watchdog_ms__mutmut_*
    hw.roboteq.configuration.x_check_watchdog_ms__mutmut_*
    hw.roboteq.settings.xǁRoboteqProtectionsǁ*
    hw.roboteq.driver.xǁRoboteqMDC2230ǁset_speeds_rpm__mutmut_*
    hw.roboteq.driver.xǁRoboteqMDC2230ǁset_commands__mutmut_*'
  [srf08]='hw.srf08.x_range_register_for__mutmut_*
    hw.srf08.x_range_for_register__mutmut_*
    hw.srf08.x_ranging_time_for_register__mutmut_*
    hw.srf08.xǁSRF08ǁstart_ranging__mutmut_*
    hw.srf08.xǁSRF08ǁread_range_cm__mutmut_*
    hw.srf08.xǁSRF08ǁcollect__mutmut_*
    hw.srf08.xǁSRF08ǁ_wait_ready__mutmut_*
    hw.sonar_array.xǁSonarFiringGroupǁ*
    hw.sonar_array.xǁRangerSonarArrayǁ_start__mutmut_*
    hw.sonar_array.xǁRangerSonarArrayǁ_finish__mutmut_*'
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
