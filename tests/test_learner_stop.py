"""The learner stops within one update of SIGTERM and writes its last checkpoint: the launcher
kills what has not stopped after 10 s, and a batch of 32 updates took longer on a slow machine
(a study run's last 995 updates were lost with their checkpoint)."""

import threading

from learner.service import LearnerService
from tests.core_fixtures import lanedrive_data
from tests.helpers import TINY as TINY_RUN
from tests.helpers import compose_run

# no transport here: no actors to pause, no weights to publish inside the batch
QUIET = ["learner.max_owed_updates=0", "learner.publish_every=1000"]


def owing_service(tmp_path) -> LearnerService:
    """A learner past its warm-up (1 update done) whose rate limit owes far more than one batch."""
    service = LearnerService(compose_run([*TINY_RUN, "transport=inproc", *QUIET]), None, tmp_path)
    service.core.add(lanedrive_data()[:300])
    service.train(max_updates=1)  # the warm-up is met here, and the warm start done
    service.intake.counters["inserted"] = 10**6
    return service


def test_a_stop_set_during_a_batch_of_updates_ends_it_after_the_update_under_way(tmp_path):
    service = owing_service(tmp_path)
    stop, real_update = threading.Event(), service.core.update

    def update_then_stop():
        metrics = real_update()
        if service.core.updates == 3:
            stop.set()  # SIGTERM arrives during the third update
        return metrics

    service.core.update = update_then_stop
    service.train(max_updates=32, stop=stop)
    assert service.core.updates == 3
    assert service.save().name == "ckpt-000000003.pt"  # the last checkpoint holds every update done


def test_without_a_stop_the_batch_runs_to_its_limit(tmp_path):
    service = owing_service(tmp_path)
    service.train(max_updates=5, stop=threading.Event())
    assert service.core.updates == 1 + 5
