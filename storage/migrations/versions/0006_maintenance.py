"""maintenance loop: work orders (at most one active per axis: a partial unique
index), their transitions, and repairs

Revision ID: 0006
Revises: 0005
"""

from alembic import op
import sqlalchemy as sa


revision = '0006'
down_revision = '0005'
branch_labels = None
depends_on = None

ONE_ACTIVE = "state IN ('open', 'acknowledged', 'repaired')"


def upgrade() -> None:
    ts = sa.DateTime(timezone=True)
    op.create_table(
        'work_orders',
        sa.Column('id', sa.Integer(), primary_key=True),
        sa.Column('axis_id', sa.Integer(), sa.ForeignKey('axes.id', ondelete='CASCADE'), nullable=False),
        sa.Column('kind', sa.String(20), nullable=False),
        sa.Column('state', sa.String(20), nullable=False),
        sa.Column('opened_at', ts, nullable=False),
        sa.Column('opened_by_result_id', sa.Integer(), sa.ForeignKey('results.id', ondelete='SET NULL'), nullable=True),
        sa.Column('alert_id', sa.Integer(), sa.ForeignKey('alerts.id', ondelete='SET NULL'), nullable=True),
        sa.Column('binding_task', sa.String(100), nullable=True),
        sa.Column('tolerance_um', sa.Float(), nullable=True),
        sa.Column('backlash_um', sa.Float(), nullable=True),
        sa.Column('backlash_uncertainty_um', sa.Float(), nullable=True),
        sa.Column('tbe_um', sa.Float(), nullable=True),
        sa.Column('tbe_uncertainty_um', sa.Float(), nullable=True),
        sa.Column('backlash_limit_um', sa.Float(), nullable=True),
        sa.Column('restore_below_um', sa.Float(), nullable=True),
        sa.Column('due_at', ts, nullable=True),
        sa.Column('recommendation', sa.Text(), nullable=False),
        sa.Column('verification_cycle_id', sa.Integer(), sa.ForeignKey('cycles.id', ondelete='SET NULL'),
                  nullable=True),
        sa.Column('verification', sa.Text(), nullable=True),
        sa.Column('closed_at', ts, nullable=True),
    )
    op.create_index('uq_work_orders_one_active', 'work_orders', ['axis_id'], unique=True,
                    sqlite_where=sa.text(ONE_ACTIVE), postgresql_where=sa.text(ONE_ACTIVE))
    op.create_index('ix_work_orders_axis_opened', 'work_orders', ['axis_id', 'opened_at'])
    op.create_table(
        'work_order_transitions',
        sa.Column('id', sa.Integer(), primary_key=True),
        sa.Column('order_id', sa.Integer(), sa.ForeignKey('work_orders.id', ondelete='CASCADE'), nullable=False),
        sa.Column('at', ts, nullable=False),
        sa.Column('from_state', sa.String(20), nullable=True),
        sa.Column('to_state', sa.String(20), nullable=False),
        sa.Column('by', sa.String(100), nullable=False),
        sa.Column('note', sa.Text(), nullable=False),
        sa.Column('figures', sa.Text(), nullable=True),
    )
    op.create_index('ix_work_order_transitions_order_id', 'work_order_transitions', ['order_id'])
    op.create_table(
        'repairs',
        sa.Column('id', sa.Integer(), primary_key=True),
        sa.Column('axis_id', sa.Integer(), sa.ForeignKey('axes.id', ondelete='CASCADE'), nullable=False),
        sa.Column('order_id', sa.Integer(), sa.ForeignKey('work_orders.id', ondelete='SET NULL'), nullable=True),
        sa.Column('kind', sa.String(30), nullable=False),
        sa.Column('note', sa.Text(), nullable=False),
        sa.Column('performed_at', ts, nullable=False),
        sa.Column('recorded_at', ts, nullable=False),
        sa.Column('recorded_by', sa.String(100), nullable=False),
        sa.Column('compensation_cycle_id', sa.Integer(), sa.ForeignKey('cycles.id', ondelete='SET NULL'),
                  nullable=True),
        sa.Column('compensation_file', sa.String(300), nullable=True),
        sa.Column('before_result_id', sa.Integer(), sa.ForeignKey('results.id', ondelete='SET NULL'), nullable=True),
    )
    op.create_index('ix_repairs_axis_performed', 'repairs', ['axis_id', 'performed_at'])


def downgrade() -> None:
    op.drop_index('ix_repairs_axis_performed', table_name='repairs')
    op.drop_table('repairs')
    op.drop_index('ix_work_order_transitions_order_id', table_name='work_order_transitions')
    op.drop_table('work_order_transitions')
    op.drop_index('ix_work_orders_axis_opened', table_name='work_orders')
    op.drop_index('uq_work_orders_one_active', table_name='work_orders')
    op.drop_table('work_orders')
