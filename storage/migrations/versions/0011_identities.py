"""a uuid for every machine and axis: the identity a dataset folder records as its
owner, so a folder written by another database (whose ids repeat) is never appended to

Revision ID: 0011
Revises: 0010
"""

import uuid

from alembic import op
import sqlalchemy as sa


revision = '0011'
down_revision = '0010'
branch_labels = None
depends_on = None

TABLES = ('machines', 'axes')


def upgrade() -> None:
    # ADD COLUMN, then an index: no table is rebuilt (a rebuild of machines or axes
    # on SQLite with foreign keys on would cascade to the rows that refer to them)
    for table in TABLES:
        op.add_column(table, sa.Column('uuid', sa.String(length=36), nullable=True))
    bind = op.get_bind()
    for table in TABLES:
        ids = bind.execute(sa.text(f"SELECT id FROM {table} WHERE uuid IS NULL")).scalars().all()
        for row_id in ids:
            bind.execute(sa.text(f"UPDATE {table} SET uuid = :u WHERE id = :i"),
                         {"u": str(uuid.uuid4()), "i": row_id})
        op.create_index(f'ix_{table}_uuid', table, ['uuid'], unique=True)


def downgrade() -> None:
    for table in reversed(TABLES):  # (no table rebuild either: SQLite >= 3.35 drops a column in place)
        op.drop_index(f'ix_{table}_uuid', table_name=table)
        op.execute(f"ALTER TABLE {table} DROP COLUMN uuid")
