"""The shipped configs compose as documented: every `fit`/`validate`/`test`/`predict` command
written in the README, docs/ (with docs/study/) or a config's own header parses
(``--print_config``: no data, no training), and so does every documented
`generate`/`audit`/`analyze` command; every config file is used by one, the lists merge as intended (a later ``callbacks+:`` appends to base.yaml's
callbacks) and base.yaml, which the CLI reads first, makes a study config alone a whole run."""

import importlib
import re
import shlex
import sys

import pytest
import yaml
from helpers.configs import compose, parsed
from helpers.locations import REPO

from voe_lightning import specs

CONFIGS = REPO / "configs"
COMMAND = re.compile(r"\b(fit|validate|test|predict)\s+--config\b")
PACKAGE_COMMAND = re.compile(r"voe_lightning\s+(generate|audit|analyze)\b")


def documented_commands(command: re.Pattern = COMMAND) -> list[tuple[str, ...]]:
    """Each documented ``command`` as its arguments after ``python -m voe_lightning``, without
    ``--ckpt_path`` (the checkpoint is not there), in order of first appearance."""
    sources = [
        REPO / "README.md",
        *sorted((REPO / "docs").rglob("*.md")),
    ]
    texts = [path.read_text() for path in sources]
    texts += [
        "\n".join(
            re.sub(r"^#\s?", "", line)
            for line in path.read_text().splitlines()
            if line.startswith("#")
        )
        for path in sorted(CONFIGS.rglob("*.yaml"))
    ]
    commands: dict[tuple[str, ...], None] = {}
    for text in texts:
        for line in re.sub(r"\\\n\s*", " ", text).splitlines():
            for match in command.finditer(line):
                words = shlex.split(re.split(r"[`|#]", line[match.start(1) :])[0])
                while "--ckpt_path" in words:
                    index = words.index("--ckpt_path")
                    del words[index : index + 2]
                commands[tuple(words)] = None
    return list(commands)


def imported(class_path: str) -> type:
    module, _, name = class_path.rpartition(".")
    return getattr(importlib.import_module(module), name)


def callbacks(config: dict) -> dict[str, dict]:
    """The trainer's callbacks by class name (each must appear once)."""
    names = [
        callback["class_path"].rsplit(".", 1)[1] for callback in config["trainer"]["callbacks"]
    ]
    assert len(names) == len(set(names)), names
    return {
        name: callback.get("init_args") or {}
        for name, callback in zip(names, config["trainer"]["callbacks"])
    }


@pytest.fixture(autouse=True)
def in_repository(monkeypatch):
    monkeypatch.chdir(REPO)  # the documented paths are relative to the repository root
    monkeypatch.setattr(sys, "argv", ["python -m voe_lightning"])  # not pytest's arguments


def test_every_config_is_in_a_documented_command():
    used = {
        word for command in documented_commands() for word in command if word.startswith("configs/")
    }
    shipped = {str(path.relative_to(REPO)) for path in CONFIGS.rglob("*.yaml")}
    assert used | {"configs/base.yaml"} == shipped


def test_an_overlay_is_visibly_one():
    """A config that only works on top of another lives in configs/overlays/, names the config it
    overlays in its first line, and comes after a parent in every documented command; every other
    study config is a whole run alone (a documented command starts with it)."""
    commands = documented_commands()
    firsts = {command[command.index("--config") + 1] for command in commands}
    overlays = sorted((CONFIGS / "overlays").glob("*.yaml"))
    assert len(overlays) >= 6
    for path in overlays:
        first_line = path.read_text().splitlines()[0]
        parents = re.findall(r"configs/\w+\.yaml", first_line)
        assert first_line.startswith("# Overlay on ") and parents, path.name
        assert all((REPO / parent).is_file() for parent in parents), first_line
        assert str(path.relative_to(REPO)) not in firsts, f"{path.name} is documented alone"
    for path in CONFIGS.glob("*.yaml"):
        if path.name != "base.yaml":
            assert str(path.relative_to(REPO)) in firsts, f"{path.name} is never documented alone"


#: The overlays a documented command may add to its one config: the paper's separate regime, one
#: concept at a time on configs/joint.yaml, and ``analyze null``'s (its untrained draws need no
#: untrained copy of themselves).
OVERLAYS_ALLOWED = {
    *(f"configs/overlays/{concept}.yaml" for concept in specs.CONCEPTS),
    "configs/overlays/untrained_null.yaml",
}


def test_a_result_is_one_config():
    """Every documented command names one config; a second only from ``OVERLAYS_ALLOWED``."""
    commands = documented_commands()
    assert len(commands) >= 40
    stacked = {
        " ".join(command)
        for command in commands
        for index, word in enumerate(command)
        if word == "--config"
        and index != command.index("--config")
        and command[index + 1] not in OVERLAYS_ALLOWED
    }
    assert stacked == set()


def test_pages_of_the_present_are_short():
    """The README is a user's page of at most 200 lines and each study page at most 300,
    current answer first (issue 71; CONTRIBUTING.md): history lives in git."""
    pages = {REPO / "README.md": 200} | {p: 300 for p in (REPO / "docs/study").glob("*.md")}
    long = {
        str(page.relative_to(REPO)): n
        for page, most in pages.items()
        if (n := len(page.read_text().splitlines())) > most
    }
    assert len(pages) > 5 and long == {}


@pytest.mark.parametrize("command", documented_commands(), ids=" ".join)
def test_documented_command_parses_into_a_complete_run(command):
    config = parsed(*command)
    model_class, _ = (imported(config[section]["class_path"]) for section in ("model", "data"))
    assert config["trainer"]["logger"]["init_args"]["name"]
    present = callbacks(config)
    assert "VOEReportCallback" in present
    if command[0] == "fit":  # trains: probes while training, checkpoints at each validation
        assert {"VOEProbeCallback", "ExpectationImages", "TQDMProgressBar"} <= present.keys()
        checkpoint = present["FinalStepCheckpoint"]
        assert checkpoint["save_last"]
        if "--trainer.val_check_interval" not in command:  # the configs' own cadence, not a study's
            assert config["trainer"]["val_check_interval"] % checkpoint["every_n_train_steps"] == 0
        model_class(**config["model"]["init_args"])  # the constructor takes the composed values


@pytest.mark.parametrize("command", documented_commands(PACKAGE_COMMAND), ids=" ".join)
def test_documented_package_command_parses(command):
    parsed(*command)


def test_command_one_trains_a_camera_learner():
    """README command 1 (``configs/quickstart.yaml``) trains the RGB-D rung, which reads what a
    depth camera and a tracker give and never the amodal ``objects`` (issue 70); the paper's
    VRNN-LRU at that size is one config away."""
    model = compose("quickstart")["model"]
    assert model["class_path"] == "voe_lightning.model.ObjectStateModel"
    assert model["init_args"]["perception"] == "rgbd"
    learner = imported(model["class_path"])(**model["init_args"])
    assert "objects" not in learner.inputs_read() and "depth" in learner.inputs_read()
    vrnn = compose("vrnn_quickstart")["model"]["class_path"]
    assert vrnn == "voe_lightning.model.VRNNLRUModel"


def test_later_configs_append_to_or_override_base():
    base = callbacks(compose("joint"))
    cpu = compose("cpu")
    assert callbacks(cpu).keys() == base.keys() | {"LearningRateMonitor"}  # callbacks+: appends
    assert callbacks(cpu)["FinalStepCheckpoint"]["every_n_train_steps"] == 2000
    assert callbacks(compose("quickstart"))["FinalStepCheckpoint"]["every_n_train_steps"] == 250
    assert cpu["trainer"]["gradient_clip_val"] == 10.0  # base.yaml's
    separate = compose("joint", "overlays/solidity")
    assert separate["data"]["class_path"] == "voe_lightning.datamodules.ConceptDataModule"
    assert separate["data"]["init_args"]["concept"] == "solidity"
    assert separate["data"]["init_args"]["root"] == "data/voe_10k"  # joint.yaml's, kept
    assert separate["data"]["init_args"]["train_examples"] == 10000
    assert separate["trainer"]["max_steps"] == 100000
    assert separate["trainer"]["logger"]["init_args"] == {
        **compose("joint")["trainer"]["logger"]["init_args"],
        "name": "solidity",
    }
    assert separate["model"]["init_args"]["learning_rate"] == 5e-5


def test_paper_config_reads_the_memory_as_the_paper_does():
    paper = compose("paper")
    arguments = paper["model"]["init_args"]
    assert arguments["controller_sees_read"] is False
    assert arguments["least_used_slots"] == arguments["memory_read_heads"] == 3
    assert arguments["learning_rate"] == 5e-6 and paper["data"]["init_args"]["batch_size"] == 10
    assert paper["trainer"]["gradient_clip_val"] is None  # the paper names no clipping
    joint = compose("joint")["model"]["init_args"]
    assert (joint["controller_sees_read"], joint["least_used_slots"]) == (True, 1)  # defaults


#: configs/paper.yaml's model, pinned: the paper's sizes and stated choices, and the open ones
#: its header names as departures (head_mixing, write_content).
PAPER_MODEL = dict(
    image_size=[64, 64],
    latent_size=256,
    mlp_sizes=[512, 512],
    memory_slots=15,
    memory_slot_size=100,
    memory_read_heads=3,
    controller_size=128,
    usage_decay=0.95,
    head_mixing="controller",
    write_content="projection",
    controller_sees_read=False,
    least_used_slots=3,
    encoder_blocks=6,
    encoder_channels=[64, 64, 128],
    encoder_mlp_size=500,
    prior_regularizer_weight=1e-4,
    learning_rate=5e-6,
    adam_betas=[0.9, 0.999],
    lr_schedule="constant",
    kl_warmup_steps=0,
    kl_free_bits=0.0,
)


def test_paper_config_pins_the_papers_choices_and_names_each_departure():
    """Every choice of the paper config is written in it (a changed model default cannot move
    it), and its header names each departure from the paper, with the setting that makes it."""
    paper = compose("paper")
    arguments = paper["model"]["init_args"]
    assert {name: arguments[name] for name in PAPER_MODEL} == PAPER_MODEL
    written = yaml.safe_load((CONFIGS / "paper.yaml").read_text())["model"]["init_args"]
    assert set(PAPER_MODEL) <= set(written)
    header = "\n".join(
        line for line in (CONFIGS / "paper.yaml").read_text().splitlines() if line.startswith("#")
    )
    for departure in (
        "head_mixing: controller",
        "write_content: projection",
        "log-std",
        "memory output",
        "sub-pixel",
        "stride of 2x1",
        "deterministic rollout",
        "bf16",
        "every 20,000 steps",
    ):
        assert departure in header, departure


def test_base_is_read_before_the_given_configs():
    """``fit --config configs/quickstart.yaml`` runs exactly what base.yaml then quickstart.yaml
    give (the CLI's default config file), and a later base.yaml would change nothing."""
    alone = compose("quickstart")
    assert alone == compose("base", "quickstart")
    assert {"VOEProbeCallback", "VOEReportCallback", "FinalStepCheckpoint"} <= callbacks(
        alone
    ).keys()
