#!/usr/bin/env bash
# Mutation testing (mutmut, from PyPI) of the modules whose decisions matter most.
#   bash bench/mutation.sh [world|filter|all] [MUTANT-NAME-GLOB...]
# (globs restrict the run to some functions, e.g. 'supersafe_ros.filter.law.x_govern__mutmut_*';
# the rest are counted as not checked)
# Works on a copy of the committed tree in a scratch folder with its own venv
# (mutmut rewrites the sources it mutates); prints the score and lists every
# surviving mutant with its diff. Runs only the fast ROS-free tests of each module.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
target="${1:-all}"
shift || true
only=("$@")
work="${MUTATION_DIR:-${TMPDIR:-/tmp}/supersafe-mutation}"
venv="$work/venv"
source "$root/scripts/ros-env.sh"
if [ ! -x "$venv/bin/mutmut" ]; then
  python3 -m venv "$venv"
  "$venv/bin/pip" install -q --disable-pip-version-check mutmut==3.8.1 numpy scipy matplotlib pyyaml pytest \
    2>&1 | grep -v "is ignored" || true
fi
run_one() {  # name, source paths (comma-separated), test files...
  local name="$1" src="$2"; shift 2
  local dir="$work/$name"
  rm -rf "$dir" && mkdir -p "$dir"
  git -C "$root" archive HEAD | tar -x -C "$dir"
  ln -sfn "$root/../shared" "$work/shared" 2>/dev/null || true
  {
    echo '[mutmut]'
    echo "source_paths ="
    for p in ${src//,/ }; do echo "    $p"; done
    echo "pytest_add_cli_args_test_selection ="
    for t in "$@"; do echo "    $t"; done
    echo 'also_copy = supersafe_ros'
    echo '    test'
  } >> "$dir/setup.cfg"
  (cd "$dir" && "$venv/bin/mutmut" run --max-children "${MUTATION_JOBS:-2}" "${only[@]}" >/dev/null 2>&1 || true)
  local res; res="$(cd "$dir" && "$venv/bin/mutmut" results --all true 2>/dev/null || true)"
  local total killed survived notests timeouts unchecked
  total=$(grep -c ': ' <<<"$res" || true)
  killed=$(grep -c ': killed' <<<"$res" || true)
  survived=$(grep -c ': survived' <<<"$res" || true)
  notests=$(grep -c ': no tests' <<<"$res" || true)
  timeouts=$(grep -c ': timeout' <<<"$res" || true)
  unchecked=$(grep -c ': not checked' <<<"$res" || true)
  echo "== $name ($src): $total mutants, $killed killed, $survived survived, $timeouts timeouts, $notests not covered by the selected tests, $unchecked not checked (outside the globs)"
  { grep -E ': (survived|no tests)' <<<"$res" || true; } | while read -r m _; do
    m="${m%:}"
    echo "--- $m"
    (cd "$dir" && "$venv/bin/mutmut" show "$m" </dev/null 2>/dev/null | grep -E '^[-+][^-+]' || true)
  done
}
case "$target" in
  world|all) run_one world supersafe_ros/sim/world.py test/test_sim_core.py test/test_sim_world_rules.py \
             test/test_sim_efficiency.py ;;&
  # the filter's decision: every module of filter/ that decides (filter/core.py before the split)
  filter|all) run_one filter supersafe_ros/filter/law.py,supersafe_ros/filter/decide.py,supersafe_ros/filter/gather.py,supersafe_ros/filter/pairs.py,supersafe_ros/filter/cluster_rows.py,supersafe_ros/filter/outputs.py,supersafe_ros/filter/inputs.py,supersafe_ros/filter/propagation.py,supersafe_ros/filter/constraints.py,supersafe_ros/filter/commands.py,supersafe_ros/filter/sent.py \
             test/test_filter_robot_filter.py test/test_filter_mutants.py test/test_filter_law.py \
             test/test_reach_radial.py test/test_filter_vectorised.py test/test_filter_bounded.py ;;
esac
