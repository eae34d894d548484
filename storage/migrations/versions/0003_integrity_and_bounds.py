"""cycles.raw_run_lost (why a raw run could not be kept; NULL: kept), and at
most one waiting manual cycle per axis (a partial unique index: the rule is atomic)

Revision ID: 0003
Revises: 0002
"""

from alembic import op
import sqlalchemy as sa


revision = '0003'
down_revision = '0002'
branch_labels = None
depends_on = None

ONE_WAITING_MANUAL = "status = 'queued' AND \"trigger\" = 'manual'"


def upgrade() -> None:
    with op.batch_alter_table('cycles') as batch:
        batch.add_column(sa.Column('raw_run_lost', sa.Text(), nullable=True))
    # older versions could leave several manual cycles waiting: keep the oldest per axis
    op.execute(
        "UPDATE cycles SET status = 'cancelled', failure_reason = 'more than one manual measurement was waiting' "
        f"WHERE {ONE_WAITING_MANUAL} AND id NOT IN "
        f"(SELECT min(id) FROM cycles WHERE {ONE_WAITING_MANUAL} GROUP BY axis_id)"
    )
    op.create_index('uq_cycles_one_waiting_manual', 'cycles', ['axis_id'], unique=True,
                    sqlite_where=sa.text(ONE_WAITING_MANUAL), postgresql_where=sa.text(ONE_WAITING_MANUAL))


def downgrade() -> None:
    op.drop_index('uq_cycles_one_waiting_manual', table_name='cycles')
    with op.batch_alter_table('cycles') as batch:
        batch.drop_column('raw_run_lost')
