"""metrology: ISO 230-2 lost motion of each result, and each axis'
worst-case temperature for the prognosis

Revision ID: 0005
Revises: 0004
"""

from alembic import op
import sqlalchemy as sa


revision = '0005'
down_revision = '0004'
branch_labels = None
depends_on = None


def _results():
    return (
        sa.Column('reversal_mean_um', sa.Float(), nullable=True),
        sa.Column('reversal_max_um', sa.Float(), nullable=True),
        sa.Column('lost_motion', sa.Text(), nullable=True),
    )


def upgrade() -> None:
    # batch mode: SQLite cannot ALTER much; on PostgreSQL these are plain ADD COLUMNs
    with op.batch_alter_table('axes') as batch:
        batch.add_column(sa.Column('worst_case_temperature_c', sa.Float(), nullable=True))
    with op.batch_alter_table('results') as batch:
        for col in _results():
            batch.add_column(col)


def downgrade() -> None:
    with op.batch_alter_table('results') as batch:
        for col in reversed(_results()):
            batch.drop_column(col.name)
    with op.batch_alter_table('axes') as batch:
        batch.drop_column('worst_case_temperature_c')
