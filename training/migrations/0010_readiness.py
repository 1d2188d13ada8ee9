# Issue 51: the readiness check (training.models.ReadinessCheck).

import django.db.models.deletion
import django.utils.timezone
from django.db import migrations, models


class Migration(migrations.Migration):

    dependencies = [
        ('training', '0009_conditions'),
    ]

    operations = [
        migrations.CreateModel(
            name='ReadinessCheck',
            fields=[
                ('id', models.BigAutoField(auto_created=True, primary_key=True, serialize=False, verbose_name='ID')),
                ('status', models.CharField(choices=[('QUEUED', 'Queued'), ('INITIALIZING', 'Initializing'), ('IN_PROGRESS', 'In progress'), ('STOPPING', 'Stopping'), ('COMPLETED', 'Completed'), ('FAILED', 'Failed'), ('CANCELED', 'Canceled')], default='QUEUED', max_length=16)),
                ('created_at', models.DateTimeField(default=django.utils.timezone.now)),
                ('started_at', models.DateTimeField(blank=True, null=True)),
                ('finished_at', models.DateTimeField(blank=True, null=True)),
                ('heartbeat_at', models.DateTimeField(blank=True, null=True)),
                ('stop_requested', models.BooleanField(default=False)),
                ('error', models.TextField(blank=True)),
                ('task_id', models.CharField(blank=True, max_length=64)),
                ('worker', models.CharField(blank=True, max_length=255)),
                ('attempts', models.PositiveSmallIntegerField(default=0)),
                ('track_id', models.CharField(max_length=64)),
                ('direction', models.CharField(choices=[('native', "Track's own direction"), ('ccw', 'Counter-clockwise'), ('cw', 'Clockwise')], default='native', max_length=8)),
                ('plan', models.JSONField(blank=True, default=dict)),
                ('results', models.JSONField(blank=True, default=dict)),
                ('verdict', models.CharField(blank=True, max_length=300)),
                ('ready', models.BooleanField(blank=True, null=True)),
                ('cells_done', models.PositiveSmallIntegerField(default=0)),
                ('cells_total', models.PositiveSmallIntegerField(default=0)),
                ('videos', models.JSONField(blank=True, default=list)),
                ('model', models.ForeignKey(on_delete=django.db.models.deletion.CASCADE, related_name='readiness_checks', to='training.racingmodel')),
            ],
            options={
                'ordering': ['-created_at'],
                'abstract': False,
            },
        ),
    ]
