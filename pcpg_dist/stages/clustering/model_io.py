"""Reading a saved cluster model back (:meth:`.model.ClusterModel.save` writes it): every tensor
checked against ``cluster_model.json`` and the method's row of
:data:`pcpg_dist.config.clusterers.CLUSTERERS` before anything is built.
"""

from __future__ import annotations

import json
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from pydantic import ValidationError
from torch import nn

from pcpg_dist.common.errors import DataError, first_line
from pcpg_dist.common.inputs import input_file
from pcpg_dist.config.clusterers import CLUSTERERS, ModelKind
from pcpg_dist.config.clustering import ClusterConfig
from pcpg_dist.stages.clustering.autoencoder import SequenceAutoencoder
from pcpg_dist.stages.clustering.features import MAX_STATES, BagVocabulary
from pcpg_dist.stages.clustering.model import (
    CONFIG_FILE,
    FORMAT_VERSION,
    WEIGHTS_FILE,
    ClusterModel,
)
from pcpg_dist.stages.clustering.policy_network import PolicyMixture
from pcpg_dist.stages.clustering.states import MAX_VOCAB

TORCH_UNREADABLE = "not a pcpg model file (torch could not read its tensors)"
#: dtypes a saved tensor may have: real floats for values, integers for keys
_FLOATS, _INTS = (torch.float32, torch.float64), (torch.int64, torch.int32)
MAX_K = 1000  # as ClusterConfig.k and tuning.k_range allow


def read_tensors(path: Path, what: str = "") -> dict[str, torch.Tensor]:
    """The named tensors of a file written by ``torch.save``: read with ``weights_only=True``
    (nothing is unpickled) and torch's warnings silenced; any other content is a one-line
    ``DataError`` that never repeats torch's advice to load with ``weights_only=False``."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            obj = torch.load(path, weights_only=True, map_location="cpu")
    except OSError as e:
        raise DataError(f"{path}: {what}cannot read it ({first_line(e)})") from None
    except Exception:  # noqa: BLE001 - UnpicklingError, EOFError, RuntimeError, ...: not our format
        raise DataError(f"{path}: {what}{TORCH_UNREADABLE}") from None
    if not isinstance(obj, dict) or not all(
        isinstance(k, str) and isinstance(v, torch.Tensor) for k, v in obj.items()
    ):
        raise DataError(
            f"{path}: {what}not a pcpg model file (it holds a {type(obj).__name__}, "
            f"not named tensors)"
        )
    return obj


def _dtype(dtype: torch.dtype) -> str:
    return str(dtype).removeprefix("torch.")


class _Weights:
    """Checks the tensors of one ``cluster_model.pt`` against what its method needs."""

    def __init__(self, path: Path, method: str, tensors: dict[str, torch.Tensor]) -> None:
        self.path, self.method, self.tensors = path, method, tensors

    def fail(self, text: str) -> DataError:
        return DataError(f"{self.path}: {text}")

    def get(
        self, name: str, shape: tuple[int | None, ...], dtypes=_FLOATS, finite: bool = True
    ) -> torch.Tensor:
        """``name``, present, of one of ``dtypes`` and of ``shape`` (None: any size there)."""
        t = self.tensors.get(name)
        if t is None:
            raise self.fail(f"no tensor '{name}', which a {self.method} model needs")
        if t.dtype not in dtypes:
            raise self.fail(
                f"{name} has dtype {_dtype(t.dtype)}; a {self.method} model stores "
                + " or ".join(_dtype(d) for d in dtypes)
            )
        if t.ndim != len(shape) or any(
            w is not None and w != n for w, n in zip(shape, t.shape, strict=True)
        ):
            want = ", ".join("any" if w is None else str(w) for w in shape)
            want = f"({want},)" if len(shape) == 1 else f"({want})"
            raise self.fail(
                f"{name} has shape {tuple(t.shape)}; a {self.method} model needs {want}"
            )
        if finite and t.is_floating_point() and not bool(torch.isfinite(t).all()):
            raise self.fail(f"{name} has non-finite values (NaN or inf); all must be finite")
        return t

    def module(self, make, prefix: str, sizes: str) -> nn.Module:
        """``make()`` loaded with the ``prefix``-named tensors, once they are checked against the
        shapes its state dict has (they follow from ``sizes``, the JSON's settings named in the
        message). The shapes come from a ``meta``-device copy, so a JSON asking for a huge network
        allocates nothing before it is refused."""
        sd = _shapes(make)
        for name, shape in sd.items():
            try:
                self.get(prefix + name, shape)
            except DataError as e:  # the sizes come from the JSON: say so
                raise DataError(f"{e} (from {sizes} in {CONFIG_FILE})") from None
        module = make()
        module.load_state_dict({n: self.tensors[prefix + n].to(torch.float32) for n in sd})
        return module


def _shapes(make) -> dict[str, tuple[int, ...]]:
    """Names and shapes of the state dict of the module ``make()`` builds, with no memory."""
    with torch.device("meta"):
        return {n: tuple(t.shape) for n, t in make().state_dict().items()}


#: the JSON key of a saved model's action count, by what the model holds
_ACTION_KEYS = {
    "policy": "n_actions",
    "bag": "bag_n_actions",
    "greedy": "bag_n_actions",
    "choice": "move_width",  # not actions: the move features' width
}
_BAG_TENSORS = {"bag_states", "bag_sa_keys"}
_GREEDY_TENSORS = {"greedy_votes", "greedy_log_share", "greedy_noise"}


@dataclass(frozen=True)
class _Parts:
    """What the method-specific tensors of a saved model give: the centroids' width and the
    vocabulary, bag or greedy mixture the model is built with."""

    width: int | None
    vocabulary: np.ndarray | None = None
    bag: BagVocabulary | None = None
    greedy: tuple[np.ndarray, np.ndarray, float] | None = None
    choice: tuple[np.ndarray, np.ndarray] | None = None


def _read_meta(cfg_path: Path) -> tuple[dict, ClusterConfig]:
    """``cluster_model.json``, checked: its sizes in range and its settings ones Step A accepts."""
    try:
        if cfg_path.stat().st_size > 1 << 20:
            raise ValueError("larger than 1 MB")
        meta = json.loads(cfg_path.read_text(encoding="utf-8"))
        method, config, state_dim, k = meta["method"], meta["config"], meta["state_dim"], meta["k"]
        if not isinstance(config, dict) or not isinstance(method, str):
            raise TypeError("'method' must be a name and 'config' a mapping")
        if type(state_dim) is not int or not 1 <= state_dim <= 1_000_000:
            raise ValueError(f"state_dim {state_dim!r}; expected an integer in 1..1000000")
        if type(k) is not int or not 1 <= k <= MAX_K:
            raise ValueError(f"k {k!r}; expected an integer in 1..{MAX_K}")
        names = meta.get("feature_names") or []
        if not isinstance(names, list) or not all(isinstance(n, str) for n in names):
            raise TypeError("'feature_names' must be a list of names")
        # the saved settings must be settings Step A accepts (bounded sizes, known method)
        known = {k: v for k, v in config.items() if k in ClusterConfig.model_fields}
        try:
            settings = ClusterConfig.model_validate(known)
        except ValidationError as e:
            first = e.errors(include_url=False)[0]
            raise ValueError(f"config.{'.'.join(map(str, first['loc']))}: {first['msg']}") from None
    except (
        ValueError,
        KeyError,
        TypeError,
        OverflowError,
        RecursionError,
        UnicodeDecodeError,
    ) as e:
        raise DataError(
            f"{cfg_path}: unreadable cluster model config ({' '.join(str(e).split())[:200]})"
        ) from None
    return meta, settings


def _model_kind(cfg_path: Path, meta: dict) -> ModelKind:
    """What the saved model of ``meta``'s method holds, once its format and method are known and
    its action count (where it has one) is in range."""
    if meta.get("format_version") != FORMAT_VERSION:
        raise DataError(
            f"{cfg_path}: format_version {meta.get('format_version')!r}, expected {FORMAT_VERSION}"
        )
    method = meta["method"]
    if method not in CLUSTERERS:
        raise DataError(f"{cfg_path}: unknown clustering method {method!r}")
    kind = CLUSTERERS[method].model
    key = _ACTION_KEYS.get(kind)
    if key is not None and (type(meta.get(key)) is not int or not 1 <= meta[key] <= 1_000_000):
        raise DataError(
            f"{cfg_path}: {key} {meta.get(key)!r}; a {method} model needs an integer in 1..1000000"
        )
    if kind == "policy" and type(meta.get("policy_time", False)) is not bool:
        raise DataError(f"{cfg_path}: policy_time {meta['policy_time']!r}; expected true or false")
    return kind


def _sees_time(kind: ModelKind, meta: dict) -> bool:
    """Whether a (checked) policy_mix model's policies see the time step; models saved before
    ``policy_time`` existed do not."""
    return kind == "policy" and meta.get("policy_time", False)


def _network_maker(kind: ModelKind, meta: dict, settings: ClusterConfig):
    """``(tensor prefix, a function building the method's network)``, or None without a network:
    the network fixes the names and shapes of its tensors."""
    d, k = meta["state_dim"], meta["k"]
    if kind == "autoencoder":
        return "ae.", lambda: SequenceAutoencoder(
            d, settings.hidden_size, settings.latent_size, settings.pooling
        )
    if kind == "policy":
        time = _sees_time(kind, meta)
        return "pm.", lambda: PolicyMixture(d, settings.hidden_size, k, meta["n_actions"], time)
    return None


def _refuse_foreign(w: _Weights, kind: ModelKind, network) -> None:
    """Refuse a tensor that a model of this kind does not have (its method's and no others)."""
    extra = {
        "visits": {"vocabulary"},
        "bag": _BAG_TENSORS,
        "greedy": _BAG_TENSORS | _GREEDY_TENSORS,
        "choice": {"choice_w", "choice_log_share"},
    }
    allowed = set(extra.get(kind, set()))
    if network is not None:
        prefix, make = network
        allowed = {prefix + n for n in _shapes(make)}
    foreign = sorted(set(w.tensors) - {"mean", "std", "centroids"} - allowed)
    if foreign:
        raise w.fail(
            f"holds tensor '{foreign[0]}', which a {w.method} model (the method in "
            f"{CONFIG_FILE}) does not have"
        )


def _read_vocabulary(w: _Weights, d: int) -> _Parts:
    """visits_kmeans: the visited-state vocabulary, the centroids' width."""
    vocab = w.get("vocabulary", (None, d))
    if not 1 <= vocab.shape[0] <= MAX_VOCAB:
        raise w.fail(
            f"vocabulary has {vocab.shape[0]} states; a visits_kmeans model has 1..{MAX_VOCAB}"
        )
    return _Parts(vocab.shape[0], vocabulary=vocab.numpy())


def _read_bag(w: _Weights, d: int, n_actions: int) -> BagVocabulary:
    """The bag vocabulary: its states and its strictly increasing state-action keys in range."""
    bs = w.get("bag_states", (None, d))
    if not 1 <= bs.shape[0] <= MAX_STATES:
        raise w.fail(f"bag_states has {bs.shape[0]} states; a {w.method} model has 1..{MAX_STATES}")
    keys = w.get("bag_sa_keys", (None,), _INTS).numpy().astype(np.int64)
    top = bs.shape[0] * n_actions
    if keys.size and (keys.min() < 0 or keys.max() >= top):
        bad = int(keys.min() if keys.min() < 0 else keys.max())
        raise w.fail(
            f"bag_sa_keys holds {bad}, outside 0..{top - 1} (bag_states x bag_n_actions "
            f"{n_actions} in {CONFIG_FILE})"
        )
    if (np.diff(keys) <= 0).any():
        raise w.fail("bag_sa_keys must be strictly increasing")
    return BagVocabulary(np.ascontiguousarray(bs.numpy(), np.float32), keys, n_actions)


def _read_greedy(w: _Weights, k: int, bag: BagVocabulary) -> tuple[np.ndarray, np.ndarray, float]:
    """The mixture of greedy policies: votes (counts), log shares and a noise level in (0, 1)."""
    gv = w.get("greedy_votes", (k, len(bag.states), bag.n_actions))
    gs = w.get("greedy_log_share", (k,))
    ge = w.get("greedy_noise", (1,))
    if bool((gv < 0).any()):
        raise w.fail("greedy_votes has negative values; votes are counts, 0 or more")
    if not 0.0 < float(ge[0]) < 1.0:
        raise w.fail(f"greedy_noise is {float(ge[0])}; it lies strictly between 0 and 1")
    return gv.numpy(), gs.numpy(), float(ge[0])


def _read_parts(w: _Weights, kind: ModelKind, meta: dict, settings: ClusterConfig) -> _Parts:
    """The method-specific tensors, checked, and the width of the space the centroids live in."""
    d, k = meta["state_dim"], meta["k"]
    if kind == "visits":
        return _read_vocabulary(w, d)
    if kind in ("bag", "greedy"):
        bag = _read_bag(w, d, meta["bag_n_actions"])
        greedy = _read_greedy(w, k, bag) if kind == "greedy" else None
        return _Parts(bag.width, bag=bag, greedy=greedy)
    if kind == "choice":
        cw = w.get("choice_w", (k, meta["move_width"]))
        return _Parts(k, choice=(cw.numpy(), w.get("choice_log_share", (k,)).numpy()))
    widths = {"summary": 1 + 2 * d, "autoencoder": settings.latent_size, "policy": k}
    return _Parts(widths[kind])


def _read_centres(
    w: _Weights, cfg_path: Path, kind: ModelKind, meta: dict, width: int | None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(mean, std, centroids)``: the normaliser (std above 0) and k centroids of ``width``."""
    d, k = meta["state_dim"], meta["k"]
    feat = {"summary": 1 + 2 * d, "choice": meta.get("move_width")}.get(kind, d)
    feat += _sees_time(kind, meta)  # the time column's normaliser
    mean = w.get("mean", (feat,)).numpy()
    std = w.get("std", (feat,)).numpy()
    if not (std > 0).all():
        raise w.fail(f"std has a value of {float(std.min())}; standard deviations are above 0")
    c = w.tensors.get("centroids")
    if c is not None and c.ndim == 2 and c.shape[0] != k:
        raise DataError(f"{cfg_path}: k {k}, but {WEIGHTS_FILE} holds {c.shape[0]} centroids")
    centroids = w.get("centroids", (k, width)).numpy()
    if kind in ("policy", "choice") and not np.array_equal(centroids, np.eye(k)):
        raise w.fail(f"centroids of a {w.method} model are the k x k identity")
    return mean, std, centroids


#: the JSON settings that size each network, named in a shape error
_NETWORK_SIZES = {
    "ae.": "state_dim, config.hidden_size, config.latent_size and config.pooling",
    "pm.": "state_dim, config.hidden_size, k and n_actions",
}


def _choice_features(cfg_path: Path, meta: dict, given: str | None) -> str:
    """The move-feature function a choice_mix model calls: the one its reader gives, which must be
    the one it was fitted with. A model file never chooses code to run (it would be a pickle)."""
    saved = meta["config"].get("move_features")
    if given is None:
        raise DataError(
            f"{cfg_path}: a choice_mix model calls the move-feature function it was fitted with "
            f"({saved!r}); pcpg runs no code a model file names: give it yourself "
            f"(pcpg classify --move-features {saved})"
        )
    if given != saved:
        raise DataError(
            f"{cfg_path}: the model was fitted with move features {saved!r}; given {given!r}"
        )
    return given


def load_model(directory: str | Path, move_features: str | None = None) -> ClusterModel:
    """Read a model written by :meth:`ClusterModel.save` (tensors only: ``weights_only=True``).

    Every tensor is checked against ``cluster_model.json`` before anything is built: the method's
    tensors and no others, their dtypes, shapes (k centroids of the method's feature width),
    finite values and ranges (std > 0, state-action keys within the bag), so a tampered or
    mismatched file is a one-line :class:`DataError` naming the file and field, never a traceback
    or a model that silently gives other labels. A ``choice_mix`` model needs ``move_features``,
    the function it was fitted with (``clustering.move_features``), from its reader.
    """
    directory = Path(directory)
    cfg_path, w_path = directory / CONFIG_FILE, directory / WEIGHTS_FILE
    for p in (cfg_path, w_path):  # the input policy: regular files, links only within the folder
        input_file(
            p,
            "cluster model file",
            folder=directory,
            missing=f"not found (is {directory} a saved cluster model?)",
        )
    meta, settings = _read_meta(cfg_path)
    kind = _model_kind(cfg_path, meta)
    spec = _choice_features(cfg_path, meta, move_features) if kind == "choice" else None
    w = _Weights(w_path, meta["method"], read_tensors(w_path))
    network = _network_maker(kind, meta, settings)
    _refuse_foreign(w, kind, network)
    parts = _read_parts(w, kind, meta, settings)
    mean, std, centroids = _read_centres(w, cfg_path, kind, meta, parts.width)
    module = None
    if network is not None:
        prefix, make = network
        module = w.module(make, prefix, _NETWORK_SIZES[prefix])
    return ClusterModel(
        meta["method"],
        meta["config"],
        meta["state_dim"],
        mean,
        std,
        centroids,
        module if kind == "autoencoder" else None,
        tuple(meta.get("feature_names") or ()),
        parts.vocabulary,
        parts.bag,
        module if kind == "policy" else None,
        parts.greedy,
        parts.choice,
        spec,
    )
