"""Peak RSS of one streamed replay or per-sample feature run, for tests/features/test_streaming.py.

    python tests/streaming_rss.py replay|features SESSION MODEL OUT BATCH_ROWS

Prints one JSON line: the peak RSS above the RSS after imports and model loading [MB].
Runs in its own process, so the peak is this run's own.
"""

from __future__ import annotations

import json
import resource
import sys
from pathlib import Path


def _rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def main() -> None:
    case, session, model_path, out, rows = sys.argv[1:6]
    from contactkit.classify.modelfile.model_file import load_model
    from contactkit.features import chain_cache
    from contactkit.features.per_sample import write_per_sample_table
    from contactkit.replay import engine
    from contactkit.replay.session_replay import replay_session

    engine.BATCH_ROWS = chain_cache.BATCH_ROWS = int(rows)
    model = load_model(Path(model_path))
    baseline = _rss_mb()
    if case == "replay":
        replay_session(Path(session), model, save=Path(out), hop_s=0.1)
    else:
        write_per_sample_table([Path(session)], Path(out))
    print(json.dumps({"above_mb": _rss_mb() - baseline}))


if __name__ == "__main__":
    main()
