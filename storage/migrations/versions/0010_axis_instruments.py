"""each axis' instruments for its uncertainty budget: the linear scale's accuracy
(short-range and class) and the thermometer's class, and its expansion coefficient

Revision ID: 0010
Revises: 0009
"""

from alembic import op
import sqlalchemy as sa


revision = '0010'
down_revision = '0009'
branch_labels = None
depends_on = None


def _columns():
    return (
        sa.Column('scale_accuracy_um', sa.Float(), nullable=True),
        sa.Column('scale_accuracy_um_per_m', sa.Float(), nullable=True),
        sa.Column('thermometer_class', sa.String(length=4), nullable=True),
        sa.Column('thermal_expansion_per_k', sa.Float(), nullable=True),
    )


def upgrade() -> None:
    # batch mode: SQLite cannot ALTER much; on PostgreSQL these are plain ADD COLUMNs
    with op.batch_alter_table('axes') as batch:
        for col in _columns():
            batch.add_column(col)


def downgrade() -> None:
    with op.batch_alter_table('axes') as batch:
        for col in reversed(_columns()):
            batch.drop_column(col.name)
