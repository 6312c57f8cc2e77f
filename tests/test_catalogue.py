"""The bad-input catalogue (issue 11) as tests: each case of ``tests/catalogue.py`` that the
library answers well is pinned here, so that no later change can make it obscure or silent.

- A case with ``raises``: exactly that exception type, raised by the library's own ``raise``
  (not numpy's or torch's error passing through), with ``match`` in its message; a CLI case
  exits with status 2 after one line on stderr.
- A valid input (``check``): the exact result.
- A documented flag (``flag``): the result carries it.
- A payload (``marker``): its command did not run.

Cases in code other branches own (``pending``: the decoder's simulator, training checkpoints)
are run and reported by ``python tests/catalogue.py``, not here.
"""

from __future__ import annotations

import re

import catalogue as cat
import pytest

CASES = [c for c in cat.cases() if c.pending is None]


@pytest.fixture(scope="module")
def ctx():
    """The catalogue's shared identifiers, records and files (its checks use the same)."""
    context = cat.ctx_singleton()
    yield context
    context.close()
    cat._CTX = None


def test_the_catalogue_is_large_and_only_other_branches_are_pending():
    every = cat.cases()
    assert len(every) >= 150
    assert {c.pending for c in every} <= {None, "decoder", "training"}
    assert len({c.area for c in CASES}) >= 10


@pytest.mark.parametrize("case", CASES, ids=[c.id for c in CASES])
def test_case(case: cat.Case, ctx, capsys):
    marker = ctx.tmp / case.marker if case.marker else None
    if case.raises is not None:
        with pytest.raises(case.raises, match=case.match) as info:
            case.call(ctx)
        err = info.value
        assert type(err) is case.raises, f"{type(err).__name__}: {err}"
        own, where = cat._raise_site(err)
        assert own, f"raised outside the library's own checks, at {where}: {err}"
        if isinstance(err, SystemExit):
            assert err.code == 2
            lines = [ln for ln in err.stderr.splitlines() if ln.strip()]
            assert len(lines) == 1 and lines[0].startswith("aeid-struct: error: "), err.stderr
            assert re.search(case.match, lines[0])
    else:
        result = case.call(ctx)
        if case.check is not None:
            assert case.check(result), cat._summary(result)
        else:
            assert case.flag is not None and case.flag(result), cat._summary(result)
    if marker is not None:
        assert not marker.exists(), "the payload's command ran"
