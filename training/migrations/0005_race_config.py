from django.db import migrations, models


class Migration(migrations.Migration):
    dependencies = [
        ("training", "0004_job_attempts_resumed_from"),
    ]

    operations = [
        migrations.AddField(
            model_name="racingmodel",
            name="race_config",
            field=models.JSONField(blank=True, default=dict),
        ),
        migrations.AddField(
            model_name="evaluationjob",
            name="race_config",
            field=models.JSONField(blank=True, default=dict),
        ),
    ]
