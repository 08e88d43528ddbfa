"""The twin's first schema: fleets, buses, tokens, batches, samples, minute aggregates,
schedules, service days, fits, diagnoses, alarms, predictions.

Revision ID: 0001
Revises:
"""

import sqlalchemy as sa
from alembic import op

revision = '0001'
down_revision = None
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.create_table('alarms',
    sa.Column('id', sa.Integer(), autoincrement=True, nullable=False),
    sa.Column('bus_id', sa.Integer(), nullable=False),
    sa.Column('kind', sa.String(length=32), nullable=False),
    sa.Column('raised_at', sa.Float(), nullable=False),
    sa.Column('data_t', sa.Float(), nullable=False),
    sa.Column('day', sa.String(length=10), nullable=False),
    sa.Column('message', sa.Text(), nullable=False),
    sa.Column('lead_s', sa.Float(), nullable=True),
    sa.PrimaryKeyConstraint('id')
    )
    op.create_index(op.f('ix_alarms_bus_id'), 'alarms', ['bus_id'], unique=False)
    op.create_table('diagnoses',
    sa.Column('bus_id', sa.Integer(), nullable=False),
    sa.Column('day', sa.String(length=10), nullable=False),
    sa.Column('diagnosed_at', sa.Float(), nullable=False),
    sa.Column('verdict', sa.String(length=64), nullable=True),
    sa.Column('status', sa.String(length=32), nullable=False),
    sa.Column('finding', sa.String(length=64), nullable=False),
    sa.Column('why', sa.Text(), nullable=False),
    sa.Column('sentence', sa.Text(), nullable=False),
    sa.PrimaryKeyConstraint('bus_id', 'day')
    )
    op.create_table('fits',
    sa.Column('id', sa.Integer(), autoincrement=True, nullable=False),
    sa.Column('bus_id', sa.Integer(), nullable=False),
    sa.Column('kind', sa.String(length=16), nullable=False),
    sa.Column('fitted_at', sa.Float(), nullable=False),
    sa.Column('t_from', sa.Float(), nullable=False),
    sa.Column('t_to', sa.Float(), nullable=False),
    sa.Column('fit_values', sa.Text(), nullable=False),
    sa.Column('nrmse', sa.Float(), nullable=True),
    sa.Column('wall_s', sa.Float(), nullable=True),
    sa.PrimaryKeyConstraint('id')
    )
    op.create_index(op.f('ix_fits_bus_id'), 'fits', ['bus_id'], unique=False)
    op.create_table('fleets',
    sa.Column('name', sa.String(length=64), nullable=False),
    sa.PrimaryKeyConstraint('name')
    )
    op.create_table('minute_aggregates',
    sa.Column('bus_id', sa.Integer(), nullable=False),
    sa.Column('t', sa.Float(precision=53), nullable=False),
    sa.Column('n', sa.Integer(), nullable=False),
    sa.Column('speed_kmh', sa.Float(), nullable=False),
    sa.Column('speed_kmh_max', sa.Float(), nullable=False),
    sa.Column('distance_km', sa.Float(), nullable=False),
    sa.Column('soc_pct', sa.Float(), nullable=True),
    sa.Column('soc_pct_min', sa.Float(), nullable=True),
    sa.Column('ambient_degc', sa.Float(), nullable=True),
    sa.Column('charging', sa.Float(), nullable=True),
    sa.Column('charger_kw', sa.Float(), nullable=True),
    sa.Column('door_open', sa.Float(), nullable=True),
    sa.PrimaryKeyConstraint('bus_id', 't'),
    sqlite_with_rowid=False
    )
    op.create_table('predictions',
    sa.Column('id', sa.Integer(), autoincrement=True, nullable=False),
    sa.Column('bus_id', sa.Integer(), nullable=False),
    sa.Column('day', sa.String(length=10), nullable=False),
    sa.Column('made_at', sa.Float(), nullable=False),
    sa.Column('data_t', sa.Float(), nullable=False),
    sa.Column('end_soc_pct', sa.Float(), nullable=False),
    sa.Column('end_low_pct', sa.Float(), nullable=False),
    sa.Column('end_high_pct', sa.Float(), nullable=False),
    sa.Column('min_high_pct', sa.Float(), nullable=False),
    sa.Column('detail', sa.Text(), nullable=False),
    sa.PrimaryKeyConstraint('id')
    )
    op.create_index(op.f('ix_predictions_bus_id'), 'predictions', ['bus_id'], unique=False)
    op.create_table('samples',
    sa.Column('bus_id', sa.Integer(), nullable=False),
    sa.Column('t', sa.Float(precision=53), nullable=False),
    sa.Column('batch_id', sa.String(length=128), nullable=False),
    sa.Column('speed_kmh', sa.Float(), nullable=False),
    sa.Column('soc_pct', sa.Float(), nullable=True),
    sa.Column('ambient_degc', sa.Float(), nullable=True),
    sa.Column('charging', sa.Float(), nullable=True),
    sa.Column('charger_kw', sa.Float(), nullable=True),
    sa.Column('door_open', sa.Float(), nullable=True),
    sa.Column('passengers', sa.Float(), nullable=True),
    sa.Column('grade_pct', sa.Float(), nullable=True),
    sa.Column('altitude_m', sa.Float(), nullable=True),
    sa.Column('battery_current_a', sa.Float(), nullable=True),
    sa.Column('battery_voltage_v', sa.Float(), nullable=True),
    sa.Column('logged_load_kw', sa.Float(), nullable=True),
    sa.PrimaryKeyConstraint('bus_id', 't'),
    sqlite_with_rowid=False
    )
    op.create_table('schedules',
    sa.Column('bus_id', sa.Integer(), nullable=False),
    sa.Column('day', sa.String(length=10), nullable=False),
    sa.Column('block', sa.Text(), nullable=False),
    sa.PrimaryKeyConstraint('bus_id', 'day')
    )
    op.create_table('service_days',
    sa.Column('bus_id', sa.Integer(), nullable=False),
    sa.Column('day', sa.String(length=10), nullable=False),
    sa.Column('t_start', sa.Float(), nullable=False),
    sa.Column('t_end', sa.Float(), nullable=False),
    sa.Column('finished_at', sa.Float(), nullable=False),
    sa.Column('state', sa.String(length=16), nullable=False),
    sa.PrimaryKeyConstraint('bus_id', 'day')
    )
    op.create_table('tokens',
    sa.Column('id', sa.Integer(), autoincrement=True, nullable=False),
    sa.Column('token_hash', sa.String(length=64), nullable=False),
    sa.Column('kind', sa.String(length=8), nullable=False),
    sa.Column('bus', sa.String(length=64), nullable=True),
    sa.Column('fleet', sa.String(length=64), nullable=True),
    sa.Column('label', sa.String(length=200), server_default='', nullable=False),
    sa.Column('created_at', sa.Float(), nullable=False),
    sa.Column('revoked', sa.Boolean(), server_default=sa.false(), nullable=False),
    sa.PrimaryKeyConstraint('id'),
    sa.UniqueConstraint('token_hash')
    )
    op.create_table('buses',
    sa.Column('id', sa.Integer(), autoincrement=True, nullable=False),
    sa.Column('name', sa.String(length=64), nullable=False),
    sa.Column('fleet', sa.String(length=64), nullable=False),
    sa.Column('reserve_soc_pct', sa.Float(), server_default='30', nullable=False),
    sa.Column('last_t', sa.Float(precision=53), nullable=True),
    sa.Column('last_soc_pct', sa.Float(), nullable=True),
    sa.Column('last_speed_kmh', sa.Float(), nullable=True),
    sa.Column('seen_at', sa.Float(precision=53), nullable=True),
    sa.ForeignKeyConstraint(['fleet'], ['fleets.name'], ),
    sa.PrimaryKeyConstraint('id'),
    sa.UniqueConstraint('name')
    )
    op.create_table('batches',
    sa.Column('bus_id', sa.Integer(), nullable=False),
    sa.Column('batch_id', sa.String(length=128), nullable=False),
    sa.Column('received_at', sa.Float(), nullable=False),
    sa.Column('n_rows', sa.Integer(), nullable=False),
    sa.Column('n_new', sa.Integer(), nullable=False),
    sa.Column('t_first', sa.Float(), nullable=False),
    sa.Column('t_last', sa.Float(), nullable=False),
    sa.Column('arrival', sa.String(length=16), nullable=False),
    sa.ForeignKeyConstraint(['bus_id'], ['buses.id'], ),
    sa.PrimaryKeyConstraint('bus_id', 'batch_id')
    )


def downgrade() -> None:
    op.drop_table('batches')
    op.drop_table('buses')
    op.drop_table('tokens')
    op.drop_table('service_days')
    op.drop_table('schedules')
    op.drop_table('samples')
    op.drop_index(op.f('ix_predictions_bus_id'), table_name='predictions')
    op.drop_table('predictions')
    op.drop_table('minute_aggregates')
    op.drop_table('fleets')
    op.drop_index(op.f('ix_fits_bus_id'), table_name='fits')
    op.drop_table('fits')
    op.drop_table('diagnoses')
    op.drop_index(op.f('ix_alarms_bus_id'), table_name='alarms')
    op.drop_table('alarms')
