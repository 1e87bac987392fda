"""Worker process: enroll participants, each taking the next free sequence slot (read, then insert)."""

import sys
import time

from sqlalchemy import func, select

from studyctl.store import StudyStore
from studyctl.store.models import Participant

url, study_id, count, worker = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), sys.argv[4]
store = StudyStore.open(url)
for i in range(count):
    with store.in_transaction(lock=f"enroll:{study_id}") as tx:
        taken = tx.scalar(select(func.count()).select_from(Participant).where(Participant.study_id == study_id))
        time.sleep(0.002)  # widen the read-to-write window a racing enroller would slip into
        store.add_participant(study_id, f"{worker}-{i}", sequence_slot=taken, tx=tx)
store.close()
print("done", flush=True)
