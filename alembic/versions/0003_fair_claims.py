"""ix_jobs_status_owner_created: fair claims between owners and per-owner queue quotas

The claim finds the owners with queued jobs by a skip scan of this index, takes each one's oldest queued job by
an index seek, and the per-owner quota counts an owner's queued jobs as an index range.

Revision ID: 0003_fair_claims
Revises: 0002_job_owner
Create Date: 2026-11-24
"""
from alembic import op

revision = "0003_fair_claims"
down_revision = "0002_job_owner"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.create_index("ix_jobs_status_owner_created", "jobs", ["status", "owner", "created_at", "id"])


def downgrade() -> None:
    op.drop_index("ix_jobs_status_owner_created", table_name="jobs")
