# Issue 51: the outside-world setting (a model's conditions; an evaluation's, a league event's).

from django.db import migrations, models


class Migration(migrations.Migration):

    dependencies = [
        ('training', '0008_race_jobs'),
    ]

    operations = [
        migrations.AddField(
            model_name='racingmodel',
            name='conditions',
            field=models.JSONField(blank=True, default=dict),
        ),
        migrations.AddField(
            model_name='evaluationjob',
            name='conditions',
            field=models.JSONField(blank=True, default=dict),
        ),
        migrations.AddField(
            model_name='evaluationjob',
            name='conditions_seed',
            field=models.PositiveIntegerField(blank=True, null=True),
        ),
        migrations.AddField(
            model_name='racejob',
            name='conditions',
            field=models.JSONField(blank=True, default=dict),
        ),
    ]
