"""erase_permit: an audited exception to the event table's append-only rule, for a withdrawal that erases data.

Revision ID: 0004
Revises: 0003

``studyctl withdraw CODE --delete-data`` writes a ``participant.erase`` audit row (hash-chained, listing the
digest of every record it erases), inserts one ``erase_permit`` row per session naming that audit row, deletes
the participant's records and then the permits, all in one transaction. The event table's delete trigger lets a
row go only while a permit for its session names a ``participant.erase`` row of the audit log; updates of
events and any change to the audit log stay refused as before.
"""
from typing import Sequence, Union

from alembic import op
import sqlalchemy as sa

revision: str = '0004'
down_revision: Union[str, Sequence[str], None] = '0003'
branch_labels: Union[str, Sequence[str], None] = None
depends_on: Union[str, Sequence[str], None] = None

_ID = sa.BigInteger().with_variant(sa.Integer(), 'sqlite')
# frozen copy of studyctl.store.erasure.ERASE_ACTION (a migration must not change with later code)
_PERMITTED = ("EXISTS (SELECT 1 FROM erase_permit p JOIN audit_log a ON a.id = p.audit_id "
              "AND a.action = 'participant.erase' WHERE p.session_id = OLD.session_id)")


def upgrade() -> None:
    op.create_table('erase_permit',
    sa.Column('session_id', _ID, autoincrement=False, nullable=False),
    sa.Column('audit_id', _ID, nullable=False),
    sa.PrimaryKeyConstraint('session_id', name=op.f('pk_erase_permit'))
    )
    if op.get_bind().dialect.name == "sqlite":
        op.execute("DROP TRIGGER event_no_delete")
        op.execute(f"CREATE TRIGGER event_no_delete BEFORE DELETE ON event WHEN NOT {_PERMITTED} "
                   "BEGIN SELECT RAISE(ABORT, 'event is append-only'); END")
        return
    op.execute(
        "CREATE FUNCTION studyctl_event_append_only() RETURNS trigger LANGUAGE plpgsql AS "
        f"$$ BEGIN IF TG_OP = 'DELETE' AND {_PERMITTED} THEN RETURN OLD; END IF; "
        "RAISE EXCEPTION '% is append-only', TG_TABLE_NAME; END $$"
    )
    op.execute("DROP TRIGGER event_append_only ON event")
    op.execute("CREATE TRIGGER event_append_only BEFORE UPDATE OR DELETE ON event "
               "FOR EACH ROW EXECUTE FUNCTION studyctl_event_append_only()")


def downgrade() -> None:
    if op.get_bind().dialect.name == "sqlite":
        op.execute("DROP TRIGGER event_no_delete")
        op.execute("CREATE TRIGGER event_no_delete BEFORE DELETE ON event "
                   "BEGIN SELECT RAISE(ABORT, 'event is append-only'); END")
    else:
        op.execute("DROP TRIGGER event_append_only ON event")
        op.execute("CREATE TRIGGER event_append_only BEFORE UPDATE OR DELETE ON event "
                   "FOR EACH ROW EXECUTE FUNCTION studyctl_append_only()")
        op.execute("DROP FUNCTION studyctl_event_append_only()")
    op.drop_table('erase_permit')
