"""webhook messages kept in the database until delivered: a restart, a receiver outage
longer than the retries, or a worker that dies while sending loses none

Revision ID: 0009
Revises: 0008
"""

from alembic import op
import sqlalchemy as sa


revision = '0009'
down_revision = '0008'
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.create_table(
        'webhook_messages',
        sa.Column('id', sa.Integer(), nullable=False),
        sa.Column('msg_id', sa.String(length=40), nullable=False),
        sa.Column('url', sa.Text(), nullable=False),
        sa.Column('event_type', sa.String(length=60), nullable=False),
        sa.Column('axis_id', sa.Integer(), nullable=False),
        sa.Column('body', sa.Text(), nullable=False),
        sa.Column('created_at', sa.DateTime(timezone=True), nullable=False),
        sa.Column('state', sa.String(length=10), nullable=False),
        sa.Column('attempts', sa.Integer(), server_default='0', nullable=False),
        sa.Column('next_at', sa.DateTime(timezone=True), nullable=False),
        sa.Column('last_status', sa.Integer(), nullable=True),
        sa.Column('last_error', sa.Text(), nullable=True),
        sa.Column('done_at', sa.DateTime(timezone=True), nullable=True),
        sa.Column('claimed_by', sa.String(length=36), nullable=True),
        sa.Column('claimed_until', sa.DateTime(timezone=True), nullable=True),
        sa.PrimaryKeyConstraint('id'),
    )
    op.create_index(op.f('ix_webhook_messages_msg_id'), 'webhook_messages', ['msg_id'], unique=False)
    op.create_index('ix_webhook_messages_state_next_at', 'webhook_messages', ['state', 'next_at'], unique=False)


def downgrade() -> None:
    op.drop_index('ix_webhook_messages_state_next_at', table_name='webhook_messages')
    op.drop_index(op.f('ix_webhook_messages_msg_id'), table_name='webhook_messages')
    op.drop_table('webhook_messages')
