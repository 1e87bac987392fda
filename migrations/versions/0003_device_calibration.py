"""device_calibration: a device's zero/calibration per study (studyctl device calibrate).

Revision ID: 0003
Revises: 0002
"""
from typing import Sequence, Union

from alembic import op
import sqlalchemy as sa
from sqlalchemy.dialects import postgresql

revision: str = '0003'
down_revision: Union[str, Sequence[str], None] = '0002'
branch_labels: Union[str, Sequence[str], None] = None
depends_on: Union[str, Sequence[str], None] = None

_JSON = sa.JSON().with_variant(postgresql.JSONB(astext_type=sa.Text()), 'postgresql')


def upgrade() -> None:
    op.create_table('device_calibration',
    sa.Column('id', sa.BigInteger().with_variant(sa.Integer(), 'sqlite'), nullable=False),
    sa.Column('study_id', sa.BigInteger().with_variant(sa.Integer(), 'sqlite'), nullable=False),
    sa.Column('device', sa.String(length=100), nullable=False),
    sa.Column('created_at', sa.DateTime(timezone=True), nullable=False),
    sa.Column('params', _JSON, nullable=False),
    sa.Column('detail', _JSON, nullable=True),
    sa.ForeignKeyConstraint(['study_id'], ['study.id'], name=op.f('fk_device_calibration_study_id_study')),
    sa.PrimaryKeyConstraint('id', name=op.f('pk_device_calibration'))
    )
    with op.batch_alter_table('device_calibration', schema=None) as batch_op:
        batch_op.create_index(batch_op.f('ix_device_calibration_study_id'), ['study_id'], unique=False)


def downgrade() -> None:
    with op.batch_alter_table('device_calibration', schema=None) as batch_op:
        batch_op.drop_index(batch_op.f('ix_device_calibration_study_id'))
    op.drop_table('device_calibration')
