"""The package as a user meets it: colcon install layout, `ros2 run` lookup, CLI, layering."""

import ast
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def console_scripts() -> list[str]:
    """Executable names declared in setup.py's console_scripts."""
    tree = ast.parse((REPO / "setup.py").read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.Dict):
            for key, value in zip(node.keys, node.values):
                if isinstance(key, ast.Constant) and key.value == "console_scripts":
                    return [ast.literal_eval(e).split("=")[0].strip() for e in value.elts]
    raise AssertionError("no console_scripts in setup.py")


def readme_workspace_commands() -> list[str]:
    """The README's commands for a ROS 2 workspace (the block after its marker)."""
    text = (REPO / "README.md").read_text()
    block = text.split("<!-- workspace-commands -->", 1)[1].split("```bash\n", 1)[1].split("```", 1)[0]
    return [line for line in block.splitlines() if line and not line.startswith("#")]


@pytest.fixture(scope="module")
def colcon_install(tmp_path_factory):
    """The README's workspace commands, run as written in a workspace holding a copy of
    the repository: colcon builds both packages, ``source install/setup.bash`` works."""
    if not (Path(sys.executable).parent / "colcon").exists():
        pytest.fail("colcon is not installed in this environment (./tasks venv installs it)")
    ws = tmp_path_factory.mktemp("ws")
    # A copy without the virtual environment, as a ROS workspace holds the package.
    shutil.copytree(REPO, ws / "src" / "rheo_ros",
                    ignore=shutil.ignore_patterns(".venv", ".git", "build", "install", "log"))
    commands = readme_workspace_commands()
    build = [c for c in commands if not c.startswith("ros2 ")]
    assert any(c.startswith("colcon build") for c in build) and "source install/setup.bash" in build
    # After sourcing, report what `ros2 run` would use: the ament index and the path.
    # `ros2 run rheo_ros NODE --help` = exec <prefix>/lib/rheo_ros/NODE --help in the
    # sourced environment; --help starts nothing.
    script = "set -e\n" + "\n".join(build) + "\n" + (
        'prefix=$(python -c "from ament_index_python.packages import get_package_prefix as p; print(p(\'rheo_ros\'))")\n'
        'for node in rheo stage estimator segmenter; do "$prefix/lib/rheo_ros/$node" --help | head -1; done\n'
        'python -c "from ament_index_python.packages import get_package_prefix as p; '
        "print(p('rheo_ros')); print(p('rheo_ros_interfaces'))\"\n")
    venv = Path(sys.executable).parent.parent
    env = dict(os.environ, VIRTUAL_ENV=str(venv), PATH=f"{venv / 'bin'}:{os.environ['PATH']}",
               AMENT_PREFIX_PATH=str(venv))
    run = subprocess.run(["bash", "-c", script], cwd=ws, env=env, capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:]
    lines = run.stdout.strip().splitlines()
    return ws / "install", [Path(p) for p in lines[-2:]], lines[:-2]


def test_colcon_installs_every_executable_where_ros2_run_looks(colcon_install):
    install, (prefix, interfaces_prefix), helps = colcon_install
    assert prefix == install / "rheo_ros" and interfaces_prefix == install / "rheo_ros_interfaces"
    names = console_scripts()
    assert {"rheo", "stage", "simulator", "segmenter", "estimator"} <= set(names)
    for name in names:
        exe = prefix / "lib" / "rheo_ros" / name
        assert exe.is_file() and os.access(exe, os.X_OK), exe
    assert (prefix / "share" / "rheo_ros" / "launch" / "rheo_ros.launch.py").is_file()
    usages = [line for line in helps if line.startswith("usage:")]
    assert len(usages) == 4 and all(u.split()[1] in ("rheo", "stage", "estimator", "segmenter") for u in usages)


def test_package_xml_is_ament_python_format_3():
    text = (REPO / "package.xml").read_text()
    assert '<package format="3">' in text
    assert "<build_type>ament_python</build_type>" in text
    assert (REPO / "resource" / "rheo_ros").is_file()


def test_core_imports_no_ros():
    code = (
        "import sys, rheo_ros.models.elements, rheo_ros.models.response, rheo_ros.models.effects, "
        "rheo_ros.fe.dynamic, rheo_ros.fe.quasistatic, rheo_ros.identification.closed_form, "
        "rheo_ros.identification.fit, rheo_ros.app.cli; "
        "print([m for m in sys.modules if m.split('.')[0] in ('rclpy', 'rosbags', 'mcap')])"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_nodes_log_warnings_through_warning_not_the_deprecated_warn():
    # rclpy keys a logger's filters by call site; its deprecated ``warn`` goes through a
    # wrapper, so every ``warn`` in a process is one site: a throttled warn after a plain
    # one raised "Requested logging filters cannot be changed between calls" and killed
    # the estimator (CI, stop 10).
    calls = []
    for path in sorted((Path(__file__).parents[1] / "rheo_ros").rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Attribute) and node.attr == "warn" and "logger" in ast.unparse(node.value):
                calls.append(f"{path.name}:{node.lineno}")
    assert calls == []


def test_bench_paper_cli_writes_the_errors(tmp_path):
    out = tmp_path / "paper.json"
    run = subprocess.run([sys.executable, "-m", "rheo_ros", "bench", "paper", "--json", str(out)],
                         capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    assert "Table I long-time" in run.stdout
    cases = json.loads(out.read_text())["cases"]
    assert [c["case"] for c in cases] == ["Table I long-time (1D)", "Table I short-time (1D)",
                                          "Table IV parameters (2D)"]
    for c in cases:
        tol = 0.1 if "2D" in c["case"] else 0.01   # % (issue targets)
        for k, err in c["closed_form"]["error_pct"].items():
            assert abs(err) <= tol, (c["case"], k, err)
    assert cases[2]["deformation_error_pct"]["closed_form"] < 1e-6


def test_cli_reports_bad_usage_without_traceback():
    run = subprocess.run([sys.executable, "-m", "rheo_ros", "bench", "nope"], capture_output=True, text=True)
    assert run.returncode == 2
    assert "Traceback" not in run.stderr


def test_message_schemas_cover_every_type_written_and_parse():
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    from rheo_ros.io.bag import message_definitions
    from rheo_ros.io.messages import TOPIC_TYPES

    schemas = {str(p.relative_to(REPO / "msg_schemas").with_suffix("")): p.read_text()
               for p in (REPO / "msg_schemas").rglob("*.msg")}
    # Every type the bags carry, and every type those use, as the typestore defines it.
    for name, text in message_definitions(TOPIC_TYPES.values()).items():
        assert schemas.get(name) == text, name
    # The package's own types: the interface package's sources, copied here so that a
    # bag or a script can decode them with no ROS install.
    interfaces = REPO / "interfaces" / "rheo_ros_interfaces"
    for kind in ("msg", "action"):
        for src in (interfaces / kind).iterdir():
            assert (REPO / "msg_schemas" / "rheo_ros_interfaces" / kind / src.name).read_text() == src.read_text()
    store = get_typestore(Stores.ROS2_KILTED)
    for name in ("rheo_ros_interfaces/msg/Phase", "rheo_ros_interfaces/msg/Estimate"):
        store.register(get_types_from_msg(schemas[name], name))
        assert name in store.types


@pytest.mark.parametrize(
    ("args", "params", "message"),
    [
        (["--effect", "nope"], None, "unknown effect 'nope'"),
        ([], "geometry: solid\n", "geometry 'solid'"),
        ([], "specimen: {width: -0.08}\n", "must be positive"),
        ([], "material: {gamma: 0.7}\n", "Poisson ratio 0.7"),
        ([], "stage: {velocity: 0.0}\n", "stage.velocity: 0.0; must be positive"),
        ([], "rates: {tactile: 30.0}\n", "rates.tactile: 30.0 Hz must divide rates.stage"),
        ([], "material: {E: true}\n", "material.E: expected float"),
        ([], "stage: {keep_time: [1, 2]}\n", "stage.keep_time: expected float"),
        ([], "bogus: 1\n", "unknown parameter(s): bogus"),
        (["--seed", "-1"], None, "simulator.seed: -1; must not be negative"),
    ],
)
def test_simulate_refuses_bad_input_in_one_line(tmp_path, args, params, message):
    cmd = [sys.executable, "-m", "rheo_ros", "simulate", "--out", str(tmp_path / "bag"), *args]
    if params is not None:
        f = tmp_path / "p.yaml"
        f.write_text("/**:\n  ros__parameters:\n" + "".join(f"    {line}\n" for line in params.splitlines()))
        cmd += ["--params-file", str(f)]
    run = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert run.returncode == 2, run.stderr
    assert message in run.stderr and "Traceback" not in run.stderr
    assert len(run.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "bag").exists()


def test_missing_params_file_and_empty_section_are_one_line_errors(tmp_path):
    empty = tmp_path / "empty.yaml"
    empty.write_text("/**:\n  ros__parameters:\n")
    for f, message in ((tmp_path / "none.yaml", "cannot read"), (empty, "no '<node>: ros__parameters:' section")):
        run = subprocess.run([sys.executable, "-m", "rheo_ros", "simulate", "--params-file", str(f),
                              "--out", str(tmp_path / "bag")], capture_output=True, text=True, timeout=120)
        assert run.returncode == 2 and message in run.stderr and "Traceback" not in run.stderr, run.stderr


def test_per_node_sections_are_merged_like_the_nodes_see_them(tmp_path):
    from rheo_ros.config.setup import parse_params

    text = "/**:\n  ros__parameters:\n    stage: {keep_time: 150}\nsimulator:\n  ros__parameters:\n    material: {E: 1.0e4}\n"
    params = parse_params(text)
    assert params["stage.keep_time"] == 150.0 and isinstance(params["stage.keep_time"], float)
    assert params["material.E"] == 1.0e4


def test_config_file_documents_exactly_the_defaults():
    from rheo_ros.config.setup import DEFAULTS, PARAM_HELP, load_params

    assert load_params(REPO / "config" / "rheo_ros.yaml") == DEFAULTS
    undocumented = [k for k in DEFAULTS if not k.startswith("effects.") and k not in PARAM_HELP]
    assert undocumented == []


def test_launch_file_starts_the_four_nodes_the_package_installs():
    """No `launch` in the package index: the file is checked as Python and against the
    executables it names (ros2 launch itself runs on a ROS 2 machine)."""
    text = (REPO / "launch" / "rheo_ros.launch.py").read_text()
    compile(text, "rheo_ros.launch.py", "exec")
    names = ast.literal_eval(text.split('for name in ', 1)[1].split(' if ', 1)[0])
    assert set(names) == {"stage", "simulator", "segmenter", "estimator"} <= set(console_scripts())


@pytest.mark.parametrize("node", ["stage", "simulator", "segmenter", "estimator"])
def test_node_help_prints_and_starts_nothing(node, tmp_path):
    """--help with a real driver must not move hardware: the node prints its parameters
    and exits before creating anything (no ROS context, no publisher)."""
    run = subprocess.run([str(Path(sys.executable).parent / node), "--help"], capture_output=True, text=True,
                         timeout=60, env=dict(os.environ, ROS_DOMAIN_ID="230"))
    assert run.returncode == 0, run.stderr
    assert run.stdout.startswith(f"usage: {node}") and "stage.autostart" in run.stdout
    assert "ready" not in run.stdout + run.stderr
