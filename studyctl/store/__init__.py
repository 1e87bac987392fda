"""The study store: SQLAlchemy models, alembic migrations, repositories, samples and the audit chain.

Public entry points:

- :class:`StudyStore` — the repository API (create_study, add_participant, start_session, add_trial,
  update_trial, append_event(s), sample_writer / read_samples, record_response,
  record_location_report, audit / verify_audit, in_transaction).
- :class:`Database` — open/create/upgrade a database by URL and run transactions.
- :class:`SampleWriter`, :func:`read_samples` — high-rate samples.
- :mod:`studyctl.store.models` — the ORM models.
"""

from studyctl.store.audit import AuditReport, verify_audit
from studyctl.store.db import Database, parse_url
from studyctl.store.repository import StudyStore
from studyctl.store.samples import SampleWriter, read_samples

__all__ = ["AuditReport", "Database", "SampleWriter", "StudyStore", "parse_url", "read_samples", "verify_audit"]
