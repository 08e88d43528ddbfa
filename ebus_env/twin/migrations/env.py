"""Alembic's environment for the twin's store: runs on the connection the store hands it
(``ebus_env.twin.store.upgrade``) or on ``sqlalchemy.url`` (``alembic upgrade head``)."""

import sqlalchemy as sa
from alembic import context

from ebus_env.twin.store import metadata

config = context.config
connection = config.attributes.get("connection")
if connection is None:
    engine = sa.create_engine(config.get_main_option("sqlalchemy.url"))
    with engine.begin() as connection:
        context.configure(connection=connection, target_metadata=metadata)
        with context.begin_transaction():
            context.run_migrations()
else:
    context.configure(connection=connection, target_metadata=metadata)
    with context.begin_transaction():
        context.run_migrations()
