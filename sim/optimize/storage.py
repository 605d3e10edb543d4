"""Study storage: Optuna RDB storages with heartbeats, and what a study was created for."""

from __future__ import annotations

import math
import os
import re
import time
import warnings
import weakref
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import TYPE_CHECKING, Any
from urllib.parse import unquote, urlsplit, urlunsplit

from tumblebot.sim.optimize.objective import Objective, OptimizeError, format_xi
from tumblebot.sim.optimize.recipes import Recipe
from tumblebot.sim.world.constants import STALL_TORQUE
from tumblebot.sim.world.physics import PhysicsProfile

if TYPE_CHECKING:
    import optuna


#: Key of the study user attribute that records what a study optimises.
STUDY_KEY = "tumblebot"
PROMOTED_PREFIX = "promoted:"
DEFAULT_STORAGE = "sqlite:///tumblebot-optuna.db"

#: The storage each study was opened from (Optuna has no public accessor for it).
_STORAGES: weakref.WeakKeyDictionary[optuna.Study, Any] = weakref.WeakKeyDictionary()


def _storage_of(study: optuna.Study) -> Any:
    storage = _STORAGES.get(study)
    if storage is None:
        raise OptimizeError("open studies with tumblebot.sim.optimize.open_study (it keeps the storage)")
    return storage


@dataclass
class StudyConfig:
    """What a study was created for, stored in its user attributes; a command that asks
    for something else is refused before anything is written."""

    weights: dict[str, float]
    xi: float | str  # "inf" in JSON
    variant: str
    recipe: str
    batch: int
    screen_batch: int
    startup: int
    seed: int
    policies: dict[str, str] = field(default_factory=dict)  # task → SHA-256 of the ONNX file
    #: what drove the episodes: "policy" (each task's bundled ONNX policy), "thesis-policy"
    #: (each task's bundled policy that sees only the thesis's 9-number observation), or a
    #: gait name (``goto``, the closed-loop navigation controller, or a scripted gait).
    #: Studies made before this field existed load as "policy".
    controller: str = "policy"
    motor_model: str = "dc"  #: the servo of every episode (part of the objective)
    stall_torque: float = STALL_TORQUE
    #: a front study's ξ values ("0", "1", "3", "inf"); empty for a single-ξ study (and for
    #: every study made before front studies existed).
    front: list[str] = field(default_factory=list)
    #: the whole physics profile (its values and digest) when it differs from ``thesis`` in
    #: more than the servo model and stall torque above; None otherwise (and for every study
    #: made before profiles existed), so those studies resume unchanged.
    physics: dict[str, Any] | None = None
    #: which episodes an efficient study's screens run: ``"own"`` (each trial's screen runs
    #: episodes no other trial runs, :func:`~tumblebot.sim.optimize.trials.screen_episodes`),
    #: or ``"shared"`` (episodes ``0..s-1`` for every trial: studies made before own screens
    #: existed, which resume so). A promotion adds episodes ``s..B-1``, shared by every full batch.
    screens: str = "shared"

    @classmethod
    def of(cls, objective: Objective, recipe: Recipe, seed: int, policies: dict[str, str],
           controller: str = "policy", physics: PhysicsProfile | None = None) -> StudyConfig:
        xi: float | str = "inf" if math.isinf(objective.xi) else objective.xi
        physics = physics or PhysicsProfile()
        kept = physics.as_fields()
        return cls(dict(objective.weights), xi, objective.variant, recipe.name, recipe.batch, recipe.screen_batch,
                   recipe.startup, seed, policies, controller, kept["motor_model"], kept["stall_torque"],
                   [format_xi(x) for x in objective.front], kept["physics"], "own")

    def profile(self) -> PhysicsProfile:
        """The study's physics profile (the world of every episode)."""
        return PhysicsProfile.of_fields(self.motor_model, self.stall_torque, self.physics)

    def objective(self) -> Objective:
        xi = math.inf if self.xi == "inf" else float(self.xi)
        front = tuple(math.inf if x == "inf" else float(x) for x in self.front)
        return Objective(dict(self.weights), xi, self.variant, front)  # type: ignore[arg-type]

    def differences(self, other: StudyConfig) -> list[str]:
        """What differs in the objective or its noise (``startup`` may change between runs, and
        a study keeps the ``screens`` it was made with)."""
        mine, theirs = asdict(self), asdict(other)
        out = [f"{k}: study has {mine[k]!r}, command asks for {theirs[k]!r}"
               for k in mine if k not in ("startup", "physics", "screens") and mine[k] != theirs[k]]
        said = any(line.startswith(("motor_model", "stall_torque")) for line in out)
        if not said and not self.profile().same_as(other.profile()):  # the values matter, not the profile's name
            out.append(f"physics: study has {self.profile().describe()}, command asks for {other.profile().describe()}")
        return out


# --------------------------------------------------------------------------- trial records
@dataclass(frozen=True)
class TrialRecord:
    """What a trial stores beside Optuna's parameters and value, typed.

    Stored as the trial's user attributes under these field names (the file format: studies
    made by earlier versions load unchanged, missing fields taking their defaults); read with
    :meth:`of` and written with :meth:`write`, never as string keys elsewhere."""

    #: each task's final-state R of every episode run so far (a screening or a full batch)
    R: dict[str, list[float]] = field(default_factory=dict)
    #: e(w), exact (W/m)
    e: float | None = None
    #: episodes per task of the trial's own batch (0 when ξ = ∞ needs none)
    batch: int = 0
    mean_R: dict[str, float] = field(default_factory=dict)
    seconds: float | None = None
    #: host:pid of the process that ran it
    worker: str | None = None
    #: why it has no result (the legs are too short, or a NaN objective); None when feasible
    infeasible: str | None = None
    #: failed by Ctrl-C or a crash mid-trial: it is redone and does not count
    interrupted: bool = False

    @classmethod
    def of(cls, trial: optuna.trial.FrozenTrial) -> TrialRecord:
        attrs = trial.user_attrs
        return cls(**{f.name: attrs[f.name] for f in fields(cls) if f.name in attrs})

    @staticmethod
    def write(trial: optuna.Trial, **values: Any) -> None:
        """Set some of the fields on a running trial (unknown names are refused)."""
        known = {f.name for f in fields(TrialRecord)}
        for name, value in values.items():
            if name not in known:
                raise TypeError(f"TrialRecord has no field {name!r}")
            trial.set_user_attr(name, value)

    @property
    def episodes(self) -> int:
        """Episodes the trial ran, over all tasks."""
        return sum(len(r) for r in self.R.values())


# --------------------------------------------------------------------------- storage
_SECRET_QUERY = re.compile(r"(?i)([?&](?:password|passwd|pwd)=)[^&]*")


def _password(url: str) -> str | None:
    try:
        return urlsplit(url).password
    except ValueError:
        return None


def redact_url(url: str) -> str:
    """``url`` as it may be shown or stored: a password in it (``user:secret@host``, or a
    ``password=`` query parameter) becomes ``***``. Keep the password out of the URL
    altogether with ``PGPASSWORD`` or a ``~/.pgpass`` file (PostgreSQL reads both)."""
    password = _password(url)
    if password:
        parts = urlsplit(url)
        user = parts.username or ""
        host = parts.netloc.rpartition("@")[2]
        url = urlunsplit(parts._replace(netloc=f"{user}:***@{host}"))
    return _SECRET_QUERY.sub(r"\1***", url)


def scrub_password(text: str, url: str) -> str:
    """``text`` (e.g. a driver's error message) with ``url``'s password replaced by ``***``."""
    secrets = [_password(url), *(m.group(0).split("=", 1)[1] for m in _SECRET_QUERY.finditer(url))]
    for secret in filter(None, secrets):
        for form in {secret, unquote(secret)}:  # as written, and as a driver decodes it
            text = text.replace(form, "***")
    return text


def open_storage(url: str, writable: bool = False, must_exist: bool = False) -> Any:
    """An Optuna RDB storage for ``url`` (``sqlite:///file.db``, ``postgresql://…``), with
    heartbeats so a trial whose process was killed is failed and not counted forever.

    For SQLite files, checked before anything is opened: ``must_exist`` refuses a file
    that is not there (a report never creates an empty database from a typo), and
    ``writable`` refuses a file or folder this process cannot write (a study is written)."""
    import optuna
    from optuna.storages import RDBStorage

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    shown = redact_url(url)  # error messages never carry the password
    if "://" not in url:
        raise OptimizeError(f"--storage {shown!r} is not a database URL (e.g. sqlite:///study.db, "
                            "postgresql://user@host/db)")
    if url.startswith("sqlite:///"):
        path = Path(url[len("sqlite:///"):])
        if str(path) and str(path) != ":memory:":
            if not path.parent.exists():
                raise OptimizeError(f"--storage {shown!r}: folder {path.parent} does not exist")
            if must_exist and not path.is_file():
                raise OptimizeError(f"--storage {shown!r}: there is no database file {path}")
            if writable and path.exists() and not os.access(path, os.R_OK | os.W_OK):
                raise OptimizeError(f"--storage {shown!r}: the database file {path} is not writable by this user")
            if writable and not os.access(path.parent, os.W_OK | os.X_OK):
                raise OptimizeError(f"--storage {shown!r}: folder {path.parent} is not writable (SQLite writes a "
                                    "journal beside the database)")
    engine_kwargs: dict[str, Any] = {}
    if url.startswith("sqlite"):
        engine_kwargs = {"connect_args": {"timeout": 60}}  # several processes share one file
    for attempt in range(5):
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
                return RDBStorage(url, engine_kwargs=engine_kwargs, heartbeat_interval=10, grace_period=60)
        except Exception as exc:  # SQLAlchemy raises many types; all mean "cannot open"
            text = str(exc)
            # Workers started together on an empty database race to create the schema; the
            # loser sees a duplicate-key (PostgreSQL) or UNIQUE-constraint (SQLite, on
            # alembic_version) error and finds the tables on its next try.
            if attempt < 4 and any(m in text for m in ("duplicate key", "already exists", "UNIQUE constraint")):
                time.sleep(0.5 + attempt)
                continue
            first = text.strip().splitlines()[0] if text.strip() else type(exc).__name__
            first = scrub_password(first, url)
            raise OptimizeError(f"--storage {shown!r} cannot be opened: {first}") from None
    raise AssertionError("unreachable")


def load_config(study: optuna.Study) -> StudyConfig | None:
    raw = study.user_attrs.get(STUDY_KEY)
    return StudyConfig(**raw) if raw else None


def load_study(storage: Any, name: str) -> optuna.Study:
    import optuna

    try:
        return optuna.load_study(study_name=name, storage=storage)
    except KeyError:
        known = [s.study_name for s in optuna.get_all_study_summaries(storage, include_best_trial=False)]
        raise OptimizeError(f"study {name!r} does not exist in this storage; studies: "
                            f"{', '.join(known) or 'none'}") from None


def open_study(storage: Any, name: str, config: StudyConfig) -> optuna.Study:
    """Create the study, or load it after checking it was made for the same objective."""
    import optuna

    study = optuna.create_study(study_name=name, storage=storage, direction="maximize", load_if_exists=True)
    _STORAGES[study] = storage
    existing = load_config(study)
    if existing is None:
        if study.trials:
            raise OptimizeError(f"study {name!r} exists but was not made by tumblebot optimize; "
                                "choose another --study")
        study.set_user_attr(STUDY_KEY, asdict(config))
        return study
    diff = existing.differences(config)
    if diff:
        raise OptimizeError(f"study {name!r} was created for a different objective; nothing was changed. "
                            + "; ".join(diff) + ". Use another --study, or repeat the original options.")
    return study


def promotions(study: optuna.Study) -> dict[int, dict[str, Any]]:
    """Full-batch results of promoted trials (efficient recipe), by trial number."""
    out: dict[int, dict[str, Any]] = {}
    for key, value in study.user_attrs.items():
        if key.startswith(PROMOTED_PREFIX) and isinstance(value, dict) and "value" in value:
            out[int(key[len(PROMOTED_PREFIX):])] = value
    return out
