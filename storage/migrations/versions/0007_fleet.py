"""fleet: workers, per-axis leases, and which worker ran a cycle and when it was due

Revision ID: 0007
Revises: 0005
"""

from alembic import op
import sqlalchemy as sa


revision = '0007'
down_revision = '0006'
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.create_table(
        'workers',
        sa.Column('id', sa.String(length=36), nullable=False),
        sa.Column('name', sa.String(length=100), nullable=False),
        sa.Column('host', sa.String(length=200), nullable=False),
        sa.Column('pid', sa.Integer(), nullable=False),
        sa.Column('axes', sa.Text(), nullable=True),
        sa.Column('lease_s', sa.Float(), nullable=False),
        sa.Column('started_at', sa.DateTime(timezone=True), nullable=False),
        sa.Column('heartbeat_at', sa.DateTime(timezone=True), nullable=False),
        sa.Column('stopped_at', sa.DateTime(timezone=True), nullable=True),
        sa.Column('takeovers', sa.Integer(), server_default='0', nullable=False),
        sa.PrimaryKeyConstraint('id'),
    )
    op.create_index('ix_workers_name', 'workers', ['name'])
    op.create_table(
        'axis_leases',
        sa.Column('axis_id', sa.Integer(), nullable=False),
        sa.Column('owner', sa.String(length=36), nullable=True),
        sa.Column('previous_owner', sa.String(length=36), nullable=True),
        sa.Column('acquired_at', sa.DateTime(timezone=True), nullable=True),
        sa.Column('expires_at', sa.DateTime(timezone=True), nullable=False),
        sa.ForeignKeyConstraint(['axis_id'], ['axes.id'], ondelete='CASCADE'),
        sa.PrimaryKeyConstraint('axis_id'),
    )
    op.create_index('ix_axis_leases_owner', 'axis_leases', ['owner'])
    with op.batch_alter_table('cycles') as batch:
        batch.add_column(sa.Column('worker', sa.String(length=36), nullable=True))
        batch.add_column(sa.Column('due_at', sa.DateTime(timezone=True), nullable=True))


def downgrade() -> None:
    with op.batch_alter_table('cycles') as batch:
        batch.drop_column('due_at')
        batch.drop_column('worker')
    op.drop_index('ix_axis_leases_owner', table_name='axis_leases')
    op.drop_table('axis_leases')
    op.drop_index('ix_workers_name', table_name='workers')
    op.drop_table('workers')
