"""jobs.owner: which API key created the job (a hash of the key, never the key)

Revision ID: 0002_job_owner
Revises: 0001_jobs
Create Date: 2026-11-21
"""
import sqlalchemy as sa
from alembic import op

revision = "0002_job_owner"
down_revision = "0001_jobs"
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table("jobs") as batch:
        batch.add_column(sa.Column("owner", sa.String(64), nullable=True))
        batch.create_index("ix_jobs_owner_created", ["owner", "created_at"])


def downgrade() -> None:
    with op.batch_alter_table("jobs") as batch:
        batch.drop_index("ix_jobs_owner_created")
        batch.drop_column("owner")
