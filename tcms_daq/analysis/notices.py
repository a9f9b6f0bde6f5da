"""Warnings and reasons with stable codes: a :class:`Notice` is its English text (a ``str``, so the CLI, the
API's ``warnings`` and every list of strings keep working) that also carries a ``code`` and the ``params`` its
text was filled with, already formatted (numbers with their unit as the English text shows them). The pages,
the report and the certificate translate a notice from the message catalogue (``notice.<code>`` with the same
``{params}``) and show the English text when a language lacks the code. A param may itself be a notice or a list
of notices (the gaps a left-out loop holds): its English is the notices' texts joined by "; ", and each is
translated by its own code; :func:`notices_of` is what a results
document keeps of them (``results["notices"]``, ``verdict["reason_notices"]``), in the order of the texts."""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from typing import Any

LIST_SEPARATOR = "; "  # between the notices of a list param, in English (the catalogue's ``list_separator``)


def _param_text(value: Any) -> str:
    return LIST_SEPARATOR.join(map(str, value)) if isinstance(value, list | tuple) else str(value)


class Notice(str):
    """English text with a stable ``code`` and its formatted ``params`` (strings, notices or lists of notices)."""

    code: str
    params: dict[str, Any]

    def __new__(cls, code: str, template: str, **params: str | Notice | Sequence[Notice]) -> Notice:
        made = super().__new__(cls, template.format(**{k: _param_text(v) for k, v in params.items()}))
        made.code = code
        made.params = dict(params)
        return made

    def __reduce__(self) -> tuple[Any, ...]:  # copy, deepcopy (dataclasses.asdict) and pickle keep the code
        return (_rebuild, (str(self), self.code, self.params))


def _rebuild(text: str, code: str, params: dict[str, Any]) -> Notice:
    made = str.__new__(Notice, text)
    made.code = code
    made.params = dict(params)
    return made


def notices_of(texts: Iterable[str]) -> list[dict[str, Any]]:
    """``{"code", "params", "text"}`` per text, in order; a text without a code gets ``code`` None; a param that
    is a notice is such a dict, a list of notices a list of them."""
    return [_as_dict(t) for t in texts]


def _as_dict(text: str) -> dict[str, Any]:
    params = dict(getattr(text, "params", {}) or {})
    return {"code": getattr(text, "code", None), "text": str(text),
            "params": {k: (_as_dict(v) if isinstance(v, Notice) else [_as_dict(n) for n in v]
                           if isinstance(v, list | tuple) else v) for k, v in params.items()}}


def notices_in(results: Mapping[str, Any]) -> list[dict[str, Any]]:
    """The notices of a results document: its ``notices`` when they match its ``warnings`` one to one, else one
    without a code per warning (results written before notices existed)."""
    warnings = results.get("warnings") or []
    kept = results.get("notices")
    if isinstance(kept, list) and len(kept) == len(warnings):
        return [dict(n) for n in kept]
    return notices_of(str(w) for w in warnings)


def prepend_warnings(results: dict[str, Any], texts: Sequence[str]) -> None:
    """Put ``texts`` before the warnings of ``results``, keeping its ``notices`` in step."""
    notices = [*notices_of(texts), *notices_in(results)]
    results["warnings"] = [*texts, *(results.get("warnings") or [])]
    results["notices"] = notices
