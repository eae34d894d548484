"""hourly trend rollups (a trend whose cost does not grow with history),
built from the results already stored

Revision ID: 0004
Revises: 0003
"""

from alembic import op
import sqlalchemy as sa


revision = '0004'
down_revision = '0003'
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.create_table(
        'trend_rollups',
        sa.Column('id', sa.Integer(), primary_key=True),
        sa.Column('axis_id', sa.Integer(), sa.ForeignKey('axes.id', ondelete='CASCADE'), nullable=False),
        sa.Column('bucket_start', sa.DateTime(timezone=True), nullable=False),
        sa.Column('n', sa.Integer(), nullable=False),
        sa.Column('b_min_cycle_id', sa.Integer(), nullable=False),
        sa.Column('b_min_um', sa.Float(), nullable=False),
        sa.Column('b_max_cycle_id', sa.Integer(), nullable=False),
        sa.Column('b_max_um', sa.Float(), nullable=False),
        sa.Column('stats', sa.LargeBinary(), nullable=False),
        sa.UniqueConstraint('axis_id', 'bucket_start', name='uq_trend_rollups_axis_bucket'),
    )
    from sqlalchemy.orm import Session

    from storage.db import rollup

    with Session(bind=op.get_bind()) as s:
        rollup.rebuild(s)
        s.flush()


def downgrade() -> None:
    op.drop_table('trend_rollups')
