"""circular tests (ISO 230-4): the test, its figures, the agreement with the TBE at b̄ and
the decision of each axis of its plane; alerts and work orders name a test as their evidence

Revision ID: 0012
Revises: 0011
"""

from alembic import op
import sqlalchemy as sa


revision = '0012'
down_revision = '0011'
branch_labels = None
depends_on = None

# ADD COLUMN without a foreign key: no table is rebuilt (a rebuild of alerts on SQLite with
# foreign keys on would set the work orders' alert_id to NULL)
EVIDENCE = (('alerts', 'raised_by_circle_id'), ('alerts', 'cleared_by_circle_id'),
            ('work_orders', 'opened_by_circle_id'))


def upgrade() -> None:
    op.create_table(
        'circular_tests',
        sa.Column('id', sa.Integer(), nullable=False),
        sa.Column('machine_id', sa.Integer(), sa.ForeignKey('machines.id', ondelete='CASCADE'), nullable=False),
        sa.Column('first_axis', sa.String(length=20), nullable=False),
        sa.Column('second_axis', sa.String(length=20), nullable=False),
        sa.Column('first_axis_id', sa.Integer(), sa.ForeignKey('axes.id', ondelete='SET NULL'), nullable=True),
        sa.Column('second_axis_id', sa.Integer(), sa.ForeignKey('axes.id', ondelete='SET NULL'), nullable=True),
        sa.Column('radius_mm', sa.Float(), nullable=False),
        sa.Column('feed_mm_min', sa.Float(), nullable=False),
        sa.Column('directions', sa.String(length=20), nullable=False),
        sa.Column('temperature_c', sa.Float(), nullable=True),
        sa.Column('utility_day', sa.Float(), nullable=True),
        sa.Column('measured_at', sa.DateTime(timezone=True), nullable=False),
        sa.Column('recorded_at', sa.DateTime(timezone=True), nullable=False),
        sa.Column('recorded_by', sa.String(length=100), nullable=True),
        sa.Column('source', sa.Text(), nullable=False),
        sa.Column('instrument', sa.Text(), nullable=False),
        sa.Column('test', sa.Text(), nullable=False),
        sa.Column('figures', sa.Text(), nullable=True),
        sa.Column('agreement', sa.Text(), nullable=True),
        sa.Column('decision', sa.Text(), nullable=True),
        sa.Column('state', sa.String(length=10), nullable=True),
        sa.PrimaryKeyConstraint('id'),
    )
    op.create_index('ix_circular_tests_machine_measured', 'circular_tests', ['machine_id', 'measured_at'])
    op.create_index(op.f('ix_circular_tests_first_axis_id'), 'circular_tests', ['first_axis_id'])
    op.create_index(op.f('ix_circular_tests_second_axis_id'), 'circular_tests', ['second_axis_id'])
    for table, column in EVIDENCE:
        op.add_column(table, sa.Column(column, sa.Integer(), nullable=True))


def downgrade() -> None:
    for table, column in reversed(EVIDENCE):  # (in place: SQLite >= 3.35 drops a column without a rebuild)
        op.execute(f"ALTER TABLE {table} DROP COLUMN {column}")
    op.drop_index(op.f('ix_circular_tests_second_axis_id'), table_name='circular_tests')
    op.drop_index(op.f('ix_circular_tests_first_axis_id'), table_name='circular_tests')
    op.drop_index('ix_circular_tests_machine_measured', table_name='circular_tests')
    op.drop_table('circular_tests')
