"""Instruction encodings as self-describing run artifacts: how a run turns sentence features into the codes its
policy is conditioned on.

A finished run's method folder ``<out>/<method>/`` holds ``encoding.json`` (``ENCODING_FILE``) beside its
``config.json``: an ``EncodingArtifact`` saying which kind of encoding the run trained, what the sentence encoder
gives it (``readout``), the code it outputs, the shapes needed to rebuild its networks, and where its (seed-stacked)
parameters lie::

    {
      "kind": "translator" | "nl-encoding-layer" | "aligned-encoding-layer" | "none" | <a registered kind>,
      "readout": "tokens" | "sentence" | "sentence+prefixes",
      "code_size": int,
      "spec": {"num_predicates": int, "num_arguments": int, "arg_size": int} | null,
      "hidden": [int, ...],
      "binary": bool,
      "continuous": bool,
      "params": {"source": "file", "path": <relative to the run root>, "entry": null | str}
                | {"source": "policy", "entry": str} | null,
      "unreadable_reason": null | str
    }

Readers (``talar_jax.agent``) need no knowledge of the method that wrote it: ``make_encoding`` loads the parameters
and calls the builder registered for the artifact's kind (``register_encoding_kind``). The built-in kinds are TALAR's
translator (``"translator"``, also Handcrafted / GLA / end-to-end TALAR translators), a dense encoding layer on a
frozen sentence embedding (``"nl-encoding-layer"``, the BERT-* baselines) and the TL generator's networks on the
sentence embedding (``"aligned-encoding-layer"``, aligned BERT-*); ``"none"`` records a run that cannot read a new
sentence, and why (e.g. One-hot: a code per training instruction).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import jax
import numpy as np

from talar_jax.baselines import AlignedEncodingLayer, NLEncodingLayer
from talar_jax.checkpoint import check_record_keys, load_tree, read_json_record, write_json_atomic
from talar_jax.language import TOKEN_READOUT, TRANSLATOR_READOUTS
from talar_jax.report import counted
from talar_jax.talar import TalarConfig, make_translate
from talar_jax.task_language import TaskLanguageSpec

ENCODING_FILE = "encoding.json"

TRANSLATOR = "translator"
NL_ENCODING_LAYER = "nl-encoding-layer"
ALIGNED_ENCODING_LAYER = "aligned-encoding-layer"
NO_ENCODING = "none"

FILE_SOURCE = "file"
POLICY_SOURCE = "policy"
POLICY_ENTRY = "conditioner"
"""The key of a policy checkpoint's params under which an encoding trained with the policy is stored."""

Encoding = Callable[[jax.Array], jax.Array]
"""features (S, F) or token states (S, T, D) -> codes (S, code_size); pure and jit-able."""
EncodingBuild = Callable[["EncodingArtifact", Any], Encoding]
"""``build(artifact, params) -> encoding``: params are one seed's parameters of the encoding."""


class EncodingError(ValueError):
    """An encoding record that cannot be read or used (one line, meant for the user)."""


@dataclasses.dataclass(frozen=True)
class ParamsSource:
    """Where an encoding's seed-stacked parameters lie.

    Attributes:
        source: ``"file"`` (a ``talar_jax.checkpoint.save_tree`` file) or ``"policy"`` (the policy checkpoint's
            params tree).
        path: with ``"file"``, the file's path relative to the run root (the method folder's parent), e.g.
            ``"talar/translator/params.msgpack"``; None with ``"policy"``.
        entry: a key of the loaded tree holding the encoding's parameters (None: the whole file).
    """

    source: str
    path: str | None = None
    entry: str | None = None

    def __post_init__(self):
        if self.source == FILE_SOURCE:
            if not self.path or Path(self.path).is_absolute():
                raise EncodingError(f"params from a file need a path relative to the run root, got {self.path!r}")
        elif self.source == POLICY_SOURCE:
            if self.path is not None or not self.entry:
                raise EncodingError("params from the policy checkpoint need an entry (its key) and no path")
        else:
            raise EncodingError(f"unknown params source {self.source!r}; valid: {FILE_SOURCE}, {POLICY_SOURCE}")

    @classmethod
    def file(cls, path: str | Path, entry: str | None = None) -> ParamsSource:
        """Parameters saved in ``<run root>/<path>`` (``entry``: a key inside the loaded tree)."""
        return cls(FILE_SOURCE, Path(path).as_posix(), entry)

    @classmethod
    def policy(cls, entry: str = POLICY_ENTRY) -> ParamsSource:
        """Parameters stored with the policy's, under ``entry`` of its checkpoint's params."""
        return cls(POLICY_SOURCE, None, entry)

    def to_json(self) -> dict[str, Any]:
        if self.source == POLICY_SOURCE:
            return {"source": self.source, "entry": self.entry}
        return {"source": self.source, "path": self.path, "entry": self.entry}

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> ParamsSource:
        if not isinstance(data, Mapping):
            raise EncodingError(f"'params' must be an object or null, got {data!r}")
        unknown = set(data) - {"source", "path", "entry"}
        if unknown:
            raise EncodingError(f"unknown keys in 'params': {', '.join(sorted(unknown))}")
        return cls(data.get("source"), data.get("path"), data.get("entry"))


@dataclasses.dataclass(frozen=True)
class EncodingArtifact:
    """A run's instruction encoding, as ``encoding.json`` records it (see the module docstring).

    Attributes:
        kind: a registered kind (``encoding_kinds()``) or ``"none"``.
        readout: what the sentence encoder gives the encoding (``talar_jax.language.TRANSLATOR_READOUTS``).
        code_size: size of the code the policy is conditioned on.
        spec: the task-language shape the encoding's networks have (translators, aligned layers), else None.
        hidden: hidden layer sizes of those networks (translator or TL generator), () if none.
        binary: the codes are 0/1 (translators; binary encoding layers).
        continuous: codes are compared by distance (continuous encoding layers), not by equality.
        params: where the seed-stacked parameters lie (None for kind ``"none"``).
        unreadable_reason: for kind ``"none"``, one line saying why the run cannot read a new sentence.
    """

    kind: str
    readout: str
    code_size: int
    spec: TaskLanguageSpec | None = None
    hidden: tuple[int, ...] = ()
    binary: bool = False
    continuous: bool = False
    params: ParamsSource | None = None
    unreadable_reason: str | None = None

    def __post_init__(self):
        object.__setattr__(self, "hidden", tuple(int(h) for h in self.hidden))
        if not isinstance(self.kind, str) or not self.kind:
            raise EncodingError(f"an encoding's kind must be a non-empty string, got {self.kind!r}")
        if self.readout not in TRANSLATOR_READOUTS:
            raise EncodingError(f"unknown readout {self.readout!r}; valid: {', '.join(TRANSLATOR_READOUTS)}")
        if isinstance(self.code_size, bool) or not isinstance(self.code_size, int) or self.code_size < 0:
            raise EncodingError(f"code_size must be an integer >= 0, got {self.code_size!r}")
        if (
            self.spec is not None
            and self.spec.size != self.code_size
            and self.kind in (TRANSLATOR, ALIGNED_ENCODING_LAYER)
        ):
            raise EncodingError(f"code_size {self.code_size} is not the size {self.spec.size} of spec {self.spec}")
        if self.kind == NO_ENCODING:
            if not self.unreadable_reason or self.params is not None:
                raise EncodingError("an encoding of kind 'none' needs an unreadable_reason and no params")
        else:
            if self.unreadable_reason is not None:
                raise EncodingError(f"only kind 'none' has an unreadable_reason (kind {self.kind!r})")
            if self.params is None:
                raise EncodingError(f"an encoding of kind {self.kind!r} needs params")
            if self.code_size < 1:
                raise EncodingError(f"an encoding of kind {self.kind!r} needs code_size >= 1")
            if self.kind in (TRANSLATOR, ALIGNED_ENCODING_LAYER) and self.spec is None:
                raise EncodingError(f"an encoding of kind {self.kind!r} needs a spec")

    # --- constructors --------------------------------------------------------------------------------------
    @classmethod
    def translator(
        cls,
        spec: TaskLanguageSpec,
        hidden: tuple[int, ...],
        readout: str,
        path: str | Path,
        entry: str | None = None,
    ) -> EncodingArtifact:
        """A translator (``talar_jax.talar.make_translate``) of TL shape ``spec``, hidden layers ``hidden``, reading
        ``readout`` features (token states with ``"tokens"``), its seed-stacked params in ``<run root>/<path>``
        (``entry``: their key in that file's tree). Its codes are hard 0/1 task-language codes."""
        return cls(
            TRANSLATOR,
            readout,
            spec.size,
            spec=spec,
            hidden=tuple(hidden),
            binary=True,
            continuous=False,
            params=ParamsSource.file(path, entry),
        )

    @classmethod
    def nl_encoding_layer(
        cls, code_size: int, binary: bool, readout: str, entry: str = POLICY_ENTRY
    ) -> EncodingArtifact:
        """A dense layer on the sentence embedding (``talar_jax.baselines.NLEncodingLayer(code_size, binary)``),
        trained with the policy and stored in its checkpoint under ``entry``; continuous (tanh) unless binary."""
        return cls(
            NL_ENCODING_LAYER,
            readout,
            int(code_size),
            binary=bool(binary),
            continuous=not binary,
            params=ParamsSource.policy(entry),
        )

    @classmethod
    def aligned_encoding_layer(
        cls, spec: TaskLanguageSpec, hidden: tuple[int, ...], binary: bool, readout: str, entry: str = POLICY_ENTRY
    ) -> EncodingArtifact:
        """The TL generator's networks on the sentence embedding (``talar_jax.baselines.AlignedEncodingLayer(spec,
        hidden, binary)``), trained with the policy and stored in its checkpoint under ``entry``; continuous (softmax
        probabilities) unless binary."""
        return cls(
            ALIGNED_ENCODING_LAYER,
            readout,
            spec.size,
            spec=spec,
            hidden=tuple(hidden),
            binary=bool(binary),
            continuous=not binary,
            params=ParamsSource.policy(entry),
        )

    @classmethod
    def unreadable(cls, reason: str, readout: str, code_size: int = 0) -> EncodingArtifact:
        """Kind ``"none"``: the run has no encoding that reads a new sentence, for ``reason`` (one line)."""
        return cls(NO_ENCODING, readout, int(code_size), unreadable_reason=reason)

    @property
    def readable(self) -> bool:
        """False for kind ``"none"``: no sentence can be encoded."""
        return self.kind != NO_ENCODING

    # --- JSON ----------------------------------------------------------------------------------------------
    def to_json(self) -> dict[str, Any]:
        """The ``encoding.json`` object (JSON-serialisable)."""
        return {
            "kind": self.kind,
            "readout": self.readout,
            "code_size": self.code_size,
            "spec": dataclasses.asdict(self.spec) if self.spec is not None else None,
            "hidden": list(self.hidden),
            "binary": self.binary,
            "continuous": self.continuous,
            "params": self.params.to_json() if self.params is not None else None,
            "unreadable_reason": self.unreadable_reason,
        }

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> EncodingArtifact:
        """The artifact of an ``encoding.json`` object; ``EncodingError`` for a malformed one."""
        check_record_keys(data, cls, {"kind", "readout", "code_size"}, EncodingError, "encoding record")
        spec, params = data.get("spec"), data.get("params")
        try:
            spec = TaskLanguageSpec(**spec) if spec is not None else None
        except (TypeError, ValueError) as error:
            raise EncodingError(f"malformed encoding spec {spec!r}: {error}") from None
        hidden = data.get("hidden") or []
        if not isinstance(hidden, (list, tuple)) or not all(
            isinstance(h, int) and not isinstance(h, bool) and h >= 1 for h in hidden
        ):
            raise EncodingError(f"'hidden' must be a list of positive integers, got {hidden!r}")
        for flag in ("binary", "continuous"):
            if not isinstance(data.get(flag, False), bool):
                raise EncodingError(f"{flag!r} must be true or false, got {data[flag]!r}")
        return cls(
            kind=data["kind"],
            readout=data["readout"],
            code_size=data["code_size"],
            spec=spec,
            hidden=tuple(hidden),
            binary=data.get("binary", False),
            continuous=data.get("continuous", False),
            params=ParamsSource.from_json(params) if params is not None else None,
            unreadable_reason=data.get("unreadable_reason"),
        )

    def write(self, method_folder: str | Path) -> Path:
        """Writes ``<method_folder>/encoding.json`` (atomically) and returns its path."""
        path = Path(method_folder) / ENCODING_FILE
        write_json_atomic(path, self.to_json())
        return path

    @classmethod
    def read(cls, method_folder: str | Path) -> EncodingArtifact:
        """The artifact in ``<method_folder>/encoding.json`` (``FileNotFoundError`` if there is none,
        ``EncodingError`` if it is malformed)."""
        return read_json_record(Path(method_folder) / ENCODING_FILE, cls.from_json, EncodingError)


def has_encoding(method_folder: str | Path) -> bool:
    """Whether a method folder holds an encoding record."""
    return (Path(method_folder) / ENCODING_FILE).is_file()


# --- kinds ---------------------------------------------------------------------------------------------------
_KINDS: dict[str, EncodingBuild] = {}


def register_encoding_kind(kind: str, build: EncodingBuild, *, replace: bool = False) -> None:
    """Makes artifacts of ``kind`` usable: ``build(artifact, params)`` returns the jit-able ``features -> codes``
    function of one seed's ``params`` (loaded as the artifact's ``params`` says). Registering a kind twice needs
    ``replace=True``; ``"none"`` is reserved."""
    if not isinstance(kind, str) or not kind or kind == NO_ENCODING:
        raise ValueError(f"cannot register encoding kind {kind!r}")
    if kind in _KINDS and not replace:
        raise ValueError(f"encoding kind {kind!r} is already registered (pass replace=True to replace it)")
    _KINDS[kind] = build


def encoding_kinds() -> tuple[str, ...]:
    """The registered kinds (built-in and added)."""
    return tuple(_KINDS)


def _build_translator(artifact: EncodingArtifact, params: Any) -> Encoding:
    config = TalarConfig(translator_hidden=artifact.hidden, translator_tokens=artifact.readout == TOKEN_READOUT)
    translate = make_translate(config, artifact.spec)
    return lambda features: translate(params, features)


def _build_nl_encoding_layer(artifact: EncodingArtifact, params: Any) -> Encoding:
    layer = NLEncodingLayer(artifact.code_size, artifact.binary)
    return lambda features: layer.apply(params, features, None)


def _build_aligned_encoding_layer(artifact: EncodingArtifact, params: Any) -> Encoding:
    layer = AlignedEncodingLayer(artifact.spec, artifact.hidden, binary=artifact.binary)
    return lambda features: layer.apply(params, features, None)


register_encoding_kind(TRANSLATOR, _build_translator)
register_encoding_kind(NL_ENCODING_LAYER, _build_nl_encoding_layer)
register_encoding_kind(ALIGNED_ENCODING_LAYER, _build_aligned_encoding_layer)


# --- loading -------------------------------------------------------------------------------------------------
def stored_encoding_params(
    artifact: EncodingArtifact, method_folder: str | Path, policy_params: Mapping[str, Any] | None = None
) -> tuple[Any, str]:
    """The encoding's stored (seed-stacked) parameters, from the file or policy entry the artifact names, and
    where they came from (a path, or ``"the policy checkpoint"``)."""
    if not artifact.readable:
        raise EncodingError(artifact.unreadable_reason)
    source = artifact.params
    if source.source == FILE_SOURCE:
        path = Path(method_folder).parent / source.path
        if not path.is_file():
            raise EncodingError(f"the encoding's parameters {path} are missing")
        tree, where = load_tree(path), str(path)
    else:
        if policy_params is None:
            raise EncodingError("the encoding's parameters are in the policy checkpoint, and none was given")
        tree, where = policy_params, "the policy checkpoint"
    if source.entry is not None:
        if not isinstance(tree, Mapping) or source.entry not in tree:
            raise EncodingError(f"{where} has no entry {source.entry!r} (the encoding's parameters)")
        tree = tree[source.entry]
    return tree, where


def encoding_params(
    artifact: EncodingArtifact, method_folder: str | Path, seed: int, policy_params: Mapping[str, Any] | None = None
) -> Any:
    """One seed's parameters of the encoding, from the file or policy entry the artifact names.

    Args:
        artifact: the run's encoding record.
        method_folder: the run's method folder (``<out>/<method>``; file paths are relative to its parent).
        seed: which seed (the leading axis of the stored, seed-stacked parameters).
        policy_params: the policy checkpoint's params (seed-stacked, as stored), needed when the artifact's params
            come from the policy.
    """
    tree, where = stored_encoding_params(artifact, method_folder, policy_params)
    return one_seed_params(tree, seed, where)


def one_seed_params(tree: Any, seed: int, where: str = "the run") -> Any:
    """Seed ``seed``'s parameters of the encoding's seed-stacked ``tree`` (stored at ``where``)."""
    leaves = jax.tree.leaves(tree)
    seeds = min((np.shape(leaf)[0] if np.ndim(leaf) else 0) for leaf in leaves) if leaves else 0
    if not 0 <= seed < seeds:
        raise EncodingError(
            f"seed {seed} is not among the {counted(seeds, 'seed')} of the encoding's parameters in {where}"
        )
    return jax.tree.map(lambda x: np.asarray(x)[seed], tree)


def make_encoding(
    artifact: EncodingArtifact, method_folder: str | Path, seed: int, policy_params: Mapping[str, Any] | None = None
) -> Encoding:
    """The jitted ``features -> codes`` function of one seed of a run: the artifact's parameters (see
    ``encoding_params``) given to the builder registered for its kind. ``EncodingError`` for kind ``"none"`` (its
    reason), an unregistered kind or missing parameters."""
    if not artifact.readable:
        raise EncodingError(artifact.unreadable_reason)
    _registered_build(artifact)  # an unregistered kind is told before its parameters are read
    return build_encoding(artifact, encoding_params(artifact, method_folder, seed, policy_params))


def build_encoding(artifact: EncodingArtifact, params: Any) -> Encoding:
    """The jitted ``features -> codes`` function of one seed's ``params`` (already loaded), by the builder
    registered for the artifact's kind."""
    return jax.jit(_registered_build(artifact)(artifact, params))


def _registered_build(artifact: EncodingArtifact) -> EncodingBuild:
    build = _KINDS.get(artifact.kind)
    if build is None:
        raise EncodingError(
            f"encoding kind {artifact.kind!r} is not registered (known: {', '.join(_KINDS)}); register it with "
            "talar_jax.encodings.register_encoding_kind before loading"
        )
    return build
