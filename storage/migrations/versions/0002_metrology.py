"""metrology of results: uncertainty, outliers, grid, decision rule

Revision ID: 0002
Revises: 0001
Create Date: 2026-11-23 18:20:00
"""

from alembic import op
import sqlalchemy as sa


revision = '0002'
down_revision = '0001'
branch_labels = None
depends_on = None

def _results():
    return (
    sa.Column('backlash_mean_uncertainty_um', sa.Float(), nullable=True),
    sa.Column('outliers_removed', sa.Integer(), nullable=True),
    sa.Column('grid_step_mm', sa.Float(), nullable=True),
    sa.Column('noise_um', sa.Float(), nullable=True),
    sa.Column('uncertainty_budget', sa.Text(), nullable=True),
    sa.Column('decision_rule', sa.String(length=10), nullable=True),
    )


def _tbe():
    return (
    sa.Column('tbe_uncertainty_um', sa.Float(), nullable=True),
    sa.Column('backlash_limit_uncertainty_um', sa.Float(), nullable=True),
    sa.Column('decision_rule', sa.String(length=10), nullable=True),
    sa.Column('reason', sa.Text(), nullable=True),
    )


def upgrade() -> None:
    with op.batch_alter_table('axes') as batch:
        batch.add_column(sa.Column('decision_rule', sa.String(length=10), nullable=False,
                                   server_default='guarded'))
    # batch mode: SQLite cannot ALTER much; on PostgreSQL these are plain ADD COLUMNs
    with op.batch_alter_table('results') as batch:
        for col in _results():
            batch.add_column(col)
    with op.batch_alter_table('tbe_results') as batch:
        for col in _tbe():
            batch.add_column(col)


def downgrade() -> None:
    with op.batch_alter_table('tbe_results') as batch:
        for col in reversed(_tbe()):
            batch.drop_column(col.name)
    with op.batch_alter_table('results') as batch:
        for col in reversed(_results()):
            batch.drop_column(col.name)
    with op.batch_alter_table('axes') as batch:
        batch.drop_column('decision_rule')
