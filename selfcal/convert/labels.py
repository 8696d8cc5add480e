"""Labels of one file joined to the labels of another: control coordinates to the points measured in the images,
image measurements to the images of a model.

Two programs rarely spell a point's name alike: a survey file says ``GCP05`` where Pix4D's BINGO file says
``GCP_GCP05``, a reference CSV ``gcp5`` where the markers say ``GCP05``. :func:`match_labels` joins them in tiers,
each label by the first tier that finds it exactly one partner, and only one to one (labels that several labels
of the other side match on a tier stay unmatched, and are named):

1. the same label;
2. the same ignoring case;
3. the same ignoring case, the separators ``_``, ``-`` and blanks, and the leading zeros of numbers (``GCP-5`` =
   ``gcp_05``);
4. as 3 after removing a prefix or suffix that one side adds to its labels (``GCP_``, ``gcp-``, ``_GCP``, a folder
   ``images/``): found from the data, as the affix whose removal from the still unmatched labels of one side makes
   the most of them match, which no label of the other side has, and which is not a number alone.

A label that is a number alone is joined on tiers 1 and 2 only, and tier 4 never leaves a number alone: tie
points are numbered (BINGO's, PAT-B's), and ``GCP_05`` must not become tie point ``5``.

What was done is said (one message per rule, with the pairs it joined); labels of the first file that still match
nothing are named with the nearest labels of the other (:func:`difflib.get_close_matches`); when none matches at
all, :func:`match_labels` raises a :class:`~selfcal.errors.BlockError` naming the first file.
Nothing here reads files or computes with coordinates.
"""
from __future__ import annotations

import difflib
import os
import re
from dataclasses import dataclass, field
from itertools import combinations

from ..errors import BlockError

__all__ = ["LabelMatch", "match_labels", "nearest_labels"]

_SEPARATOR_RE = re.compile(r"[_\-\s]+")
_NUMBER_RE = re.compile(r"\d+")
#: pairs shown in a message
_SHOWN = 3
#: unmatched labels listed (each with its nearest labels) in a message
_LISTED = 5


def _lower(text: str) -> str:
    """Lower case, character by character (the length stays, so that an affix found here cuts the original)."""
    if text.isascii():
        return text.lower()
    return "".join(c.lower() if len(c.lower()) == 1 else c for c in text)


def _without_separators(text: str) -> str:
    return _SEPARATOR_RE.sub("", text)


def _without_leading_zeros(text: str) -> str:
    return _NUMBER_RE.sub(lambda m: m.group().lstrip("0") or "0", text)


#: rule -> (its words in a message, its normalisation), in the order they are applied
_RULES = {
    "case": ("case", _lower),
    "separators": ("separators ('_', '-', ' ')", _without_separators),
    "zeros": ("leading zeros", _without_leading_zeros),
}


def _key(text: str) -> str:
    """Tier 3's form of a label."""
    return _without_leading_zeros(_without_separators(_lower(text)))


def _is_number(text: str) -> bool:
    return text.isdigit() or _without_separators(text).isdigit()


def _rules_needed(a: str, b: str) -> tuple[str, ...]:
    """The fewest of the rules under which ``a`` and ``b`` are the same."""
    names = tuple(_RULES)
    for size in range(len(names) + 1):
        for subset in combinations(names, size):
            x, y = a, b
            for name in names:
                if name in subset:
                    x, y = _RULES[name][1](x), _RULES[name][1](y)
            if x == y:
                return subset
    return names


@dataclass(frozen=True)
class LabelMatch:
    """The join of the labels of a first file to those of a second."""

    #: label of the first file -> its partner in the second (matched labels only)
    partner: dict
    #: labels of the first file without a partner, in the file's order
    unmatched: list
    #: what was done, one line each: the rules that joined labels, ambiguities, the labels left unmatched
    messages: list = field(default_factory=list)
    #: the last of ``messages`` when labels were left unmatched (they are named with their nearest), else ""
    unmatched_message: str = ""

    @property
    def renamed(self) -> dict:
        """Partner -> label of the first file, for the pairs whose labels differ."""
        return {b: a for a, b in self.partner.items() if a != b}


def nearest_labels(label: str, candidates, n: int = 3) -> list[str]:
    """Up to ``n`` labels of ``candidates`` that look like ``label`` (:func:`difflib.get_close_matches`, ignoring
    case; among the labels that are numbers for a number, among the others for a name)."""
    return _Nearest(candidates)(label, n)


class _Nearest:
    """:func:`nearest_labels` over one set of candidates, prepared once."""

    def __init__(self, candidates):
        self.lowered: dict = {True: {}, False: {}}
        for c in candidates:
            self.lowered[_is_number(str(c))].setdefault(_lower(str(c)), str(c))
        self.keys = {k: list(v) for k, v in self.lowered.items()}

    def __call__(self, label: str, n: int = 3) -> list[str]:
        kind = _is_number(str(label))
        found = difflib.get_close_matches(_lower(str(label)), self.keys[kind], n=n, cutoff=0.6)
        return [self.lowered[kind][f] for f in found]


def _listed(labels, candidates, limit: int = _LISTED) -> str:
    nearest = _Nearest(candidates)
    parts = []
    for label in labels[:limit]:
        near = nearest(label)
        parts.append(f"'{label}' (nearest there: {', '.join(repr(x) for x in near)})" if near else
                     f"'{label}' (nothing alike there)")
    return ", ".join(parts) + (f" and {len(labels) - limit} more" if len(labels) > limit else "")


def _examples(labels, name: str, limit: int = _LISTED) -> str:
    """A few labels of a file, those that are not numbers first (tie points are numbered)."""
    named = [x for x in labels if not _is_number(x)]
    numbers = len(labels) - len(named)
    shown = ", ".join(repr(x) for x in (named or labels)[:limit]) + (" and more" if len(named or labels) > limit else "")
    if named and numbers:
        return f"the labels of {name} that are not numbers: {shown} ({numbers} more are numbers)"
    if named:
        return f"the labels of {name}: {shown}"
    return f"the labels of {name} are numbers: {shown}"


def _by_form(labels, form) -> dict:
    out: dict = {}
    for label in labels:
        out.setdefault(form(label), []).append(label)
    return out


def _pairs(left: dict, right: dict, ambiguous: dict) -> dict:
    """left label -> right label for the forms that exactly one label of each side has (``left``, ``right``: form
    -> labels); forms held by more labels go to ``ambiguous``."""
    pairs = {}
    for form, labels in left.items():
        if form not in right:
            continue
        if len(labels) == 1 and len(right[form]) == 1:
            pairs[labels[0]] = right[form][0]
        else:
            ambiguous[frozenset(labels) | frozenset(right[form])] = (labels, right[form])
    return pairs


def _cut(label: str, kind: str, affix: str) -> str | None:
    """``label`` without ``affix`` (lower case) at its start (``kind`` "prefix") or end; None if it has none."""
    low = _lower(label)
    if kind == "prefix":
        return label[len(affix):] if low.startswith(affix) and len(low) > len(affix) else None
    return label[:len(label) - len(affix)] if low.endswith(affix) and len(low) > len(affix) else None


def _affix(left: list, right: list, all_left: list, all_right: list):
    """Tier 4's (side with the affix: "left" or "right", "prefix" or "suffix", the affix in lower case), or None."""
    scores: dict = {}
    for side, having, other in (("right", right, left), ("left", left, right)):
        targets = {_key(x) for x in other if not _is_number(x)}
        if not targets:
            continue
        for label in having:
            if _is_number(label):
                continue                            # every cut of a number leaves a number or has one as affix
            key = _key(label)
            # a cut that matches has its key at the end (a prefix removed) or the start (a suffix) of the label's
            hits = [("prefix", t) for t in (key[j:] for j in range(1, len(key))) if t in targets] + \
                   [("suffix", t) for t in (key[:j] for j in range(1, len(key))) if t in targets]
            if not hits:
                continue
            low = _lower(label)
            for i in range(1, len(low)):
                for kind, affix, rest in (("prefix", low[:i], low[i:]), ("suffix", low[i:], low[:i])):
                    if (kind, _key(rest)) in hits and not _is_number(rest):
                        scores.setdefault((side, kind, affix), set()).add(_key(rest))
    best = None
    for (side, kind, affix), keys in scores.items():
        if not _without_separators(affix) or _is_number(affix):
            continue                                # a number is part of a name, never an affix
        other_all = all_left if side == "right" else all_right
        if any(_cut(x, kind, affix) is not None or _lower(x) == affix for x in other_all):
            continue                                # the other side has it too: not what one side adds
        score = (len(keys), len(affix))
        if best is None or score > best[0]:
            best = (score, (side, kind, affix))
    return None if best is None else best[1]


def match_labels(labels, others, *, path: str, other_path: str, what: str = "control labels",
                 required: bool = True) -> LabelMatch:
    """Join ``labels`` (of the file ``path``) to ``others`` (of ``other_path``) as the module's docstring says.

    ``what`` names the first file's labels in messages ("control labels", "image names"). With ``required``, a
    first file none of whose labels matches raises a BlockError naming ``path``, with the nearest labels of the other
    file for a few of them and the number of labels on each side. Messages name the files by their base names.
    """
    labels = list(dict.fromkeys(str(x) for x in labels))
    others = list(dict.fromkeys(str(x) for x in others))
    name = os.path.basename(str(path).rstrip("/")) or str(path)
    other_name = os.path.basename(str(other_path).rstrip("/")) or str(other_path)
    other_set = set(others)
    partner = {x: x for x in labels if x in other_set}
    ambiguous: dict = {}
    stuck: set = set()

    def open_labels():
        taken = set(partner.values())
        return ([x for x in labels if x not in partner and x not in stuck],
                [x for x in others if x not in taken and x not in stuck])

    for form, numbers in ((_lower, True), (_key, False)):
        left, right = open_labels()
        if not numbers:
            left, right = [x for x in left if not _is_number(x)], [x for x in right if not _is_number(x)]
        if left and right:
            partner.update(_pairs(_by_form(left, form), _by_form(right, form), ambiguous))
        for lefts, rights in ambiguous.values():
            stuck.update(lefts)
            stuck.update(rights)
    left, right = open_labels()
    found_affix = _affix(left, right, labels, others) if left and right else None
    cut_side: dict = {}
    if found_affix is not None:
        side, kind, affix = found_affix
        having = right if side == "right" else left
        cut = {x: _cut(x, kind, affix) for x in having}
        rest = {x: r for x, r in cut.items() if r is not None and not _is_number(r)}
        plain = left if side == "right" else right
        pairs = _pairs(_by_form([x for x in plain if not _is_number(x)], _key),
                       _by_form(list(rest), lambda x: _key(rest[x])), ambiguous)
        for a, b in pairs.items():
            first, second = (a, b) if side == "right" else (b, a)
            partner[first] = second
            cut_side[first] = side
    messages = _rule_messages(labels, partner, cut_side, found_affix, what, name, other_name)
    for lefts, rights in ambiguous.values():
        messages.append(f"not matched, as they are the same ignoring case, separators and leading zeros: "
                        f"{', '.join(repr(x) for x in lefts)} of {name} and {', '.join(repr(x) for x in rights)} "
                        f"of {other_name}")
    unmatched = [x for x in labels if x not in partner]
    spare = [x for x in others if x not in set(partner.values())]
    n = len(labels)
    if not partner and required:
        raise BlockError(path, f"none of its {n} {what} matches one of the {len(others)} labels of {other_name}, "
                               f"also ignoring case, '_', '-', blanks and leading zeros and after removing a prefix or "
                               f"suffix that one side adds to its labels: {_listed(unmatched, spare)}; "
                               f"{_examples(others, other_name)}. Rename the labels of one file so that they agree")
    left_over = ""
    if unmatched and partner:
        left_over = (f"{len(unmatched)} of the {n} {what} of {name} {'matches' if len(unmatched) == 1 else 'match'} "
                     f"nothing in {other_name}: {_listed(unmatched, spare)}")
        messages.append(left_over)
    return LabelMatch(partner, unmatched, messages, left_over)


def _rule_messages(labels, partner, cut_side, found_affix, what, name, other_name) -> list[str]:
    """One message per way labels were joined (the rules, the affix), with its pairs."""
    groups: dict = {}
    for a in labels:
        b = partner.get(a)
        if b is None or a == b:
            continue
        x, y, original = a, b, None
        if a in cut_side:
            _, kind, affix = found_affix
            holder = b if cut_side[a] == "right" else a
            original = holder[:len(affix)] if kind == "prefix" else holder[len(holder) - len(affix):]
            if cut_side[a] == "right":
                y = _cut(b, kind, affix)
            else:
                x = _cut(a, kind, affix)
        groups.setdefault((a in cut_side, _rules_needed(x, y)), []).append((a, b, original))
    messages = []
    n = len(labels)
    for (affixed, rules), pairs in groups.items():
        how = []
        if affixed:
            side, kind, _ = found_affix
            originals = "' or '".join(dict.fromkeys(o for _, _, o in pairs))
            how.append(f"after removing the {kind} '{originals}' of {other_name if side == 'right' else name}'s "
                       f"labels")
        if rules:
            words = [_RULES[r][0] for r in rules]
            how.append("ignoring " + (words[0] if len(words) == 1 else ", ".join(words[:-1]) + " and " + words[-1]))
        shown = ", ".join(f"{a} = {b}" for a, b, _ in pairs[:_SHOWN]) + (", ..." if len(pairs) > _SHOWN else "")
        messages.append(f"{what} matched {' and '.join(how)} ({name} to {other_name}): {len(pairs)} of {n} "
                        f"({shown})")
    return messages
