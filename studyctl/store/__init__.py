"""The study store: SQLAlchemy models, alembic migrations, repositories, samples and the audit chain.

Public entry points:

- :class:`StudyStore` (``studyctl.store.repository``) — the repository API: create_study, get_study,
  add_participant, set_participant_status, start_session, update_session, add_trial, update_trial,
  append_event(s), events_frame, sample_writer / read_samples, record_response,
  record_location_report, audit / verify_audit, in_transaction(lock=…, durable=…), reading.
- :class:`StudyReader` (``studyctl.store.reader``) — the read side of one stored study: participants,
  sessions (with their plans), trials with their events, location reports and stored scene truth as
  frozen rows read once, samples and questionnaire answers. Analysis reads stored studies only through it.
- :class:`Database` (``studyctl.store.db``) — open/create/upgrade a database by URL, transactions.
- :class:`SampleWriter`, :func:`read_samples` (``studyctl.store.samples``) — high-rate samples.
- ``studyctl.store.workspace`` — init_workspace, open_study, resolve_database (``--db`` /
  ``STUDYCTL_DB`` / ``studyctl.toml``).
- ``studyctl.store.status`` — study_status; ``studyctl.store.maintenance`` — check_database,
  upgrade_database; ``studyctl.store.identity`` — IdentityKey, random_code;
  ``studyctl.store.pgserver`` — ThrowawayPostgres (tests, benchmarks).
- :mod:`studyctl.store.models` — the ORM models.
"""

from studyctl.store.audit import AuditReport, verify_audit
from studyctl.store.db import Database, parse_url
from studyctl.store.reader import StudyReader
from studyctl.store.repository import StudyStore
from studyctl.store.samples import SampleWriter, read_samples

__all__ = [
    "AuditReport",
    "Database",
    "SampleWriter",
    "StudyReader",
    "StudyStore",
    "parse_url",
    "read_samples",
    "verify_audit",
]
