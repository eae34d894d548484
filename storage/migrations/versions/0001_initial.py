"""initial schema: machines, axes, tasks, cycles, results, curves, tbe, alerts, keys

Revision ID: 0001
Revises: 
Create Date: 2026-11-22 04:44:29.406733
"""

from alembic import op
import sqlalchemy as sa


revision = '0001'
down_revision = None
branch_labels = None
depends_on = None


def upgrade() -> None:

    op.create_table('api_keys',
    sa.Column('id', sa.Integer(), nullable=False),
    sa.Column('name', sa.String(length=100), nullable=False),
    sa.Column('role', sa.String(length=10), nullable=False),
    sa.Column('key_prefix', sa.String(length=20), nullable=False),
    sa.Column('key_sha256', sa.String(length=64), nullable=False),
    sa.Column('created_at', sa.DateTime(timezone=True), nullable=False),
    sa.Column('revoked_at', sa.DateTime(timezone=True), nullable=True),
    sa.PrimaryKeyConstraint('id'),
    sa.UniqueConstraint('key_sha256'),
    sa.UniqueConstraint('name')
    )
    op.create_table('machines',
    sa.Column('id', sa.Integer(), nullable=False),
    sa.Column('name', sa.String(length=100), nullable=False),
    sa.Column('description', sa.Text(), nullable=False),
    sa.Column('created_at', sa.DateTime(timezone=True), nullable=False),
    sa.PrimaryKeyConstraint('id'),
    sa.UniqueConstraint('name')
    )
    op.create_table('axes',
    sa.Column('id', sa.Integer(), nullable=False),
    sa.Column('machine_id', sa.Integer(), nullable=False),
    sa.Column('name', sa.String(length=20), nullable=False),
    sa.Column('transmission_mm_per_rev', sa.Float(), nullable=False),
    sa.Column('screw_lead_mm', sa.Float(), nullable=False),
    sa.Column('position_gain_per_s', sa.Float(), nullable=False),
    sa.Column('travel_start_mm', sa.Float(), nullable=False),
    sa.Column('travel_end_mm', sa.Float(), nullable=False),
    sa.Column('controller_url', sa.String(length=300), nullable=False),
    sa.Column('measure_feed_mm_min', sa.Float(), nullable=False),
    sa.Column('measure_acceleration_mm_s2', sa.Float(), nullable=False),
    sa.Column('warning_fraction', sa.Float(), nullable=False),
    sa.Column('schedule_interval_s', sa.Float(), nullable=True),
    sa.Column('schedule_cron', sa.String(length=120), nullable=True),
    sa.Column('schedule_enabled', sa.Boolean(), nullable=False),
    sa.Column('in_service_since', sa.DateTime(timezone=True), nullable=False),
    sa.Column('created_at', sa.DateTime(timezone=True), nullable=False),
    sa.ForeignKeyConstraint(['machine_id'], ['machines.id'], ondelete='CASCADE'),
    sa.PrimaryKeyConstraint('id'),
    sa.UniqueConstraint('machine_id', 'name')
    )
    with op.batch_alter_table('axes', schema=None) as batch_op:
        batch_op.create_index(batch_op.f('ix_axes_machine_id'), ['machine_id'], unique=False)

    op.create_table('cycles',
    sa.Column('id', sa.Integer(), nullable=False),
    sa.Column('uuid', sa.String(length=36), nullable=False),
    sa.Column('axis_id', sa.Integer(), nullable=False),
    sa.Column('trigger', sa.String(length=20), nullable=False),
    sa.Column('requested_by', sa.String(length=100), nullable=True),
    sa.Column('status', sa.String(length=20), nullable=False),
    sa.Column('requested_at', sa.DateTime(timezone=True), nullable=False),
    sa.Column('started_at', sa.DateTime(timezone=True), nullable=True),
    sa.Column('finished_at', sa.DateTime(timezone=True), nullable=True),
    sa.Column('failure_reason', sa.Text(), nullable=True),
    sa.Column('temperature_c', sa.Float(), nullable=True),
    sa.Column('utility_day', sa.Float(), nullable=True),
    sa.Column('uncertainty_um', sa.Float(), nullable=True),
    sa.Column('run_file', sa.String(length=200), nullable=True),
    sa.ForeignKeyConstraint(['axis_id'], ['axes.id'], ondelete='CASCADE'),
    sa.PrimaryKeyConstraint('id'),
    sa.UniqueConstraint('uuid')
    )
    with op.batch_alter_table('cycles', schema=None) as batch_op:
        batch_op.create_index(batch_op.f('ix_cycles_axis_id'), ['axis_id'], unique=False)
        batch_op.create_index('ix_cycles_axis_requested', ['axis_id', 'requested_at'], unique=False)
        batch_op.create_index(batch_op.f('ix_cycles_status'), ['status'], unique=False)

    op.create_table('machining_tasks',
    sa.Column('id', sa.Integer(), nullable=False),
    sa.Column('axis_id', sa.Integer(), nullable=False),
    sa.Column('name', sa.String(length=100), nullable=False),
    sa.Column('profile', sa.String(length=10), nullable=False),
    sa.Column('radius_mm', sa.Float(), nullable=True),
    sa.Column('angle_deg', sa.Float(), nullable=True),
    sa.Column('feed_mm_min', sa.Float(), nullable=False),
    sa.Column('tolerance_um', sa.Float(), nullable=False),
    sa.ForeignKeyConstraint(['axis_id'], ['axes.id'], ondelete='CASCADE'),
    sa.PrimaryKeyConstraint('id'),
    sa.UniqueConstraint('axis_id', 'name')
    )
    with op.batch_alter_table('machining_tasks', schema=None) as batch_op:
        batch_op.create_index(batch_op.f('ix_machining_tasks_axis_id'), ['axis_id'], unique=False)

    op.create_table('results',
    sa.Column('id', sa.Integer(), nullable=False),
    sa.Column('cycle_id', sa.Integer(), nullable=False),
    sa.Column('axis_id', sa.Integer(), nullable=False),
    sa.Column('measured_at', sa.DateTime(timezone=True), nullable=False),
    sa.Column('temperature_c', sa.Float(), nullable=True),
    sa.Column('utility_day', sa.Float(), nullable=True),
    sa.Column('backlash_mean_um', sa.Float(), nullable=False),
    sa.Column('backlash_min_um', sa.Float(), nullable=False),
    sa.Column('backlash_max_um', sa.Float(), nullable=False),
    sa.Column('backlash_std_um', sa.Float(), nullable=False),
    sa.Column('useful_travel_start_mm', sa.Float(), nullable=False),
    sa.Column('useful_travel_end_mm', sa.Float(), nullable=False),
    sa.Column('n_samples', sa.Integer(), nullable=False),
    sa.Column('peak_speed_mm_min', sa.Float(), nullable=False),
    sa.Column('uncertainty_um', sa.Float(), nullable=True),
    sa.Column('state', sa.String(length=10), nullable=True),
    sa.Column('binding_task', sa.String(length=100), nullable=True),
    sa.Column('backlash_limit_um', sa.Float(), nullable=True),
    sa.Column('message', sa.Text(), nullable=True),
    sa.ForeignKeyConstraint(['axis_id'], ['axes.id'], ondelete='CASCADE'),
    sa.ForeignKeyConstraint(['cycle_id'], ['cycles.id'], ondelete='CASCADE'),
    sa.PrimaryKeyConstraint('id'),
    sa.UniqueConstraint('cycle_id')
    )
    with op.batch_alter_table('results', schema=None) as batch_op:
        batch_op.create_index('ix_results_axis_measured', ['axis_id', 'measured_at'], unique=False)

    op.create_table('alerts',
    sa.Column('id', sa.Integer(), nullable=False),
    sa.Column('axis_id', sa.Integer(), nullable=False),
    sa.Column('kind', sa.String(length=30), nullable=False),
    sa.Column('raised_at', sa.DateTime(timezone=True), nullable=False),
    sa.Column('raised_by_result_id', sa.Integer(), nullable=True),
    sa.Column('cleared_at', sa.DateTime(timezone=True), nullable=True),
    sa.Column('cleared_by_result_id', sa.Integer(), nullable=True),
    sa.Column('acknowledged_at', sa.DateTime(timezone=True), nullable=True),
    sa.Column('acknowledged_by', sa.String(length=100), nullable=True),
    sa.Column('task_name', sa.String(length=100), nullable=True),
    sa.Column('tbe_um', sa.Float(), nullable=True),
    sa.Column('tolerance_um', sa.Float(), nullable=True),
    sa.Column('backlash_um', sa.Float(), nullable=True),
    sa.Column('backlash_limit_um', sa.Float(), nullable=True),
    sa.Column('message', sa.Text(), nullable=False),
    sa.ForeignKeyConstraint(['axis_id'], ['axes.id'], ondelete='CASCADE'),
    sa.ForeignKeyConstraint(['cleared_by_result_id'], ['results.id'], ondelete='SET NULL'),
    sa.ForeignKeyConstraint(['raised_by_result_id'], ['results.id'], ondelete='SET NULL'),
    sa.PrimaryKeyConstraint('id')
    )
    with op.batch_alter_table('alerts', schema=None) as batch_op:
        batch_op.create_index('ix_alerts_axis_cleared', ['axis_id', 'cleared_at'], unique=False)

    op.create_table('curves',
    sa.Column('id', sa.Integer(), nullable=False),
    sa.Column('result_id', sa.Integer(), nullable=False),
    sa.Column('name', sa.String(length=60), nullable=False),
    sa.Column('position_start_mm', sa.Float(), nullable=False),
    sa.Column('position_step_mm', sa.Float(), nullable=False),
    sa.Column('n_points', sa.Integer(), nullable=False),
    sa.Column('values_f32', sa.LargeBinary(), nullable=False),
    sa.ForeignKeyConstraint(['result_id'], ['results.id'], ondelete='CASCADE'),
    sa.PrimaryKeyConstraint('id'),
    sa.UniqueConstraint('result_id', 'name')
    )
    op.create_table('lead_criteria',
    sa.Column('id', sa.Integer(), nullable=False),
    sa.Column('result_id', sa.Integer(), nullable=False),
    sa.Column('direction', sa.String(length=10), nullable=False),
    sa.Column('e_p_um', sa.Float(), nullable=False),
    sa.Column('e_p_um_per_1000mm', sa.Float(), nullable=False),
    sa.Column('v_u_um', sa.Float(), nullable=False),
    sa.Column('v_300_um', sa.Float(), nullable=False),
    sa.Column('v_2pi_um', sa.Float(), nullable=False),
    sa.Column('n_strokes', sa.Integer(), nullable=False),
    sa.ForeignKeyConstraint(['result_id'], ['results.id'], ondelete='CASCADE'),
    sa.PrimaryKeyConstraint('id'),
    sa.UniqueConstraint('result_id', 'direction')
    )
    op.create_table('tbe_results',
    sa.Column('id', sa.Integer(), nullable=False),
    sa.Column('result_id', sa.Integer(), nullable=False),
    sa.Column('task_name', sa.String(length=100), nullable=False),
    sa.Column('profile', sa.String(length=10), nullable=False),
    sa.Column('radius_mm', sa.Float(), nullable=True),
    sa.Column('angle_deg', sa.Float(), nullable=True),
    sa.Column('feed_mm_min', sa.Float(), nullable=False),
    sa.Column('gain_per_s', sa.Float(), nullable=False),
    sa.Column('tolerance_um', sa.Float(), nullable=False),
    sa.Column('tbe_um', sa.Float(), nullable=False),
    sa.Column('backlash_limit_um', sa.Float(), nullable=True),
    sa.Column('state', sa.String(length=10), nullable=False),
    sa.ForeignKeyConstraint(['result_id'], ['results.id'], ondelete='CASCADE'),
    sa.PrimaryKeyConstraint('id')
    )
    with op.batch_alter_table('tbe_results', schema=None) as batch_op:
        batch_op.create_index('ix_tbe_result', ['result_id'], unique=False)




def downgrade() -> None:

    with op.batch_alter_table('tbe_results', schema=None) as batch_op:
        batch_op.drop_index('ix_tbe_result')

    op.drop_table('tbe_results')
    op.drop_table('lead_criteria')
    op.drop_table('curves')
    with op.batch_alter_table('alerts', schema=None) as batch_op:
        batch_op.drop_index('ix_alerts_axis_cleared')

    op.drop_table('alerts')
    with op.batch_alter_table('results', schema=None) as batch_op:
        batch_op.drop_index('ix_results_axis_measured')

    op.drop_table('results')
    with op.batch_alter_table('machining_tasks', schema=None) as batch_op:
        batch_op.drop_index(batch_op.f('ix_machining_tasks_axis_id'))

    op.drop_table('machining_tasks')
    with op.batch_alter_table('cycles', schema=None) as batch_op:
        batch_op.drop_index(batch_op.f('ix_cycles_status'))
        batch_op.drop_index('ix_cycles_axis_requested')
        batch_op.drop_index(batch_op.f('ix_cycles_axis_id'))

    op.drop_table('cycles')
    with op.batch_alter_table('axes', schema=None) as batch_op:
        batch_op.drop_index(batch_op.f('ix_axes_machine_id'))

    op.drop_table('axes')
    op.drop_table('machines')
    op.drop_table('api_keys')

