"""Session leases (one writer per session) and sample-chunk digests (records sealed into the audit chain).

Revision ID: 0002
Revises: 0001
Create Date: 2026-11-24 22:30:00

A database that already holds records gets one ``records.coverage_start`` audit row naming the highest
id of each record kind: those older records were written before studyctl sealed records and are reported
as not covered (instead of as inserted) by ``studyctl audit verify``.
"""
import hashlib
import json
from datetime import UTC, datetime
from typing import Sequence, Union

from alembic import op
import sqlalchemy as sa

# revision identifiers, used by Alembic.
revision: str = '0002'
down_revision: Union[str, Sequence[str], None] = '0001'
branch_labels: Union[str, Sequence[str], None] = None
depends_on: Union[str, Sequence[str], None] = None

_ID = sa.BigInteger().with_variant(sa.Integer(), 'sqlite')
_KINDS = {"trial": "trial", "event": "event", "answer": "questionnaire_response", "report": "location_report",
          "chunk": "sample_chunk"}


def _canonical(value) -> str:
    # frozen copy of studyctl.store.audit.canonical_json (a migration must not change with later code)
    return json.dumps(value, sort_keys=True, separators=(",", ":"), ensure_ascii=False, allow_nan=False)


def _coverage_start(bind) -> None:
    last = {k: int(bind.execute(sa.text(f"SELECT COALESCE(MAX(id), 0) FROM {table}")).scalar() or 0)
            for k, table in _KINDS.items()}
    if not any(last.values()):
        return
    count, prev = bind.execute(sa.text("SELECT count, hash FROM audit_head WHERE id = 1")).one()
    row = {"id": int(count) + 1, "at": datetime.now(UTC).isoformat(timespec="microseconds"),
           "actor": "studyctl db upgrade", "action": "records.coverage_start", "entity": None, "entity_id": None,
           "details": _canonical(last)}
    digest = hashlib.sha256((prev + _canonical(row)).encode("utf-8")).hexdigest()
    bind.execute(sa.text("INSERT INTO audit_log (id, at, actor, action, entity, entity_id, details, prev_hash, hash) "
                         "VALUES (:id, :at, :actor, :action, :entity, :entity_id, :details, :prev, :hash)"),
                 {**row, "prev": prev, "hash": digest})
    bind.execute(sa.text("UPDATE audit_head SET count = :c, hash = :h WHERE id = 1"), {"c": row["id"], "h": digest})


def upgrade() -> None:
    """Upgrade schema."""
    op.create_table('session_lease',
    sa.Column('session_id', _ID, autoincrement=False, nullable=False),
    sa.Column('token', sa.String(length=64), nullable=False),
    sa.Column('pid', sa.Integer(), nullable=False),
    sa.Column('host', sa.String(length=200), nullable=False),
    sa.Column('acquired_at', sa.DateTime(timezone=True), nullable=False),
    sa.Column('heartbeat_at', sa.DateTime(timezone=True), nullable=False),
    sa.ForeignKeyConstraint(['session_id'], ['session.id'], name=op.f('fk_session_lease_session_id_session')),
    sa.PrimaryKeyConstraint('session_id', name=op.f('pk_session_lease'))
    )
    with op.batch_alter_table('sample_chunk', schema=None) as batch_op:
        batch_op.add_column(sa.Column('digest', sa.String(length=64), nullable=True))
    _coverage_start(op.get_bind())


def downgrade() -> None:
    """Downgrade schema."""
    with op.batch_alter_table('sample_chunk', schema=None) as batch_op:
        batch_op.drop_column('digest')
    op.drop_table('session_lease')
